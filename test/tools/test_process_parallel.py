"""`process` on several workers (spawned processes, Ray actors): the same output bag as one
worker, message for message and byte for byte, the same counts and drops; the stitching
rules on their own; progress, the summary line and the command line."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import signal
from pathlib import Path
from typing import Any

import pytest
from helpers import REPO, run_cli, small_sl_graph
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.errors import BagError
from depth_nodes.graph.description import load_graph_config
from depth_nodes.ros.dds import PROFILE_VARIABLES
from depth_nodes.sim import StereoSimConfig
from depth_nodes.sim.projector import ProjectorSimConfig
from depth_nodes.sim.stereo import simulate_stereo
from depth_nodes.tools.bags.engines import LocalEngine
from depth_nodes.tools.bags.generate import frame_messages
from depth_nodes.tools.bags.io import BagReader, BagWriter, serialize
from depth_nodes.tools.bags.process import default_config_path, process_bag
from depth_nodes.tools.bags.report import ProcessReport, Progress
from depth_nodes.tools.bags.segments import (
    END,
    Segment,
    SegmentJob,
    SegmentResult,
    claim_spill,
    run_segment,
    segments,
)
from depth_nodes.tools.bags.stitching import stitch
from depth_nodes.tools.bags.structured_light import (
    REFERENCE_FILE,
    StructuredLightBagConfig,
    write_structured_light_bag,
)

pytestmark = pytest.mark.slow

#: Bound on a wait for a worker's answer (not a timing assertion: it only ends a hang).
WAIT_S = 60.0
STEREO = StereoSimConfig(width=160, height=120, n_frames=8, seed=7, colour=True)
#: The frame whose right image the stereo bag leaves out: a drop every run must count.
MISSING_RIGHT = 5
SL = StructuredLightBagConfig(
    sim=ProjectorSimConfig(width=96, height=72, focal_px=84.0, projector_width=96,
                           projector_height=72, projector_focal_px=75.0, seed=5),
    steps=4, period=8.0, sequences=3, speckle_frames=1)


def _messages(bag: Path) -> list[tuple[str, int, bytes]]:
    with BagReader(bag) as reader:
        return [(m.topic, m.timestamp, m.data) for m in reader.messages()]


def _counts(report: ProcessReport) -> tuple[Any, ...]:
    drops = {node: dict(c) for node, c in report.drops.items() if c}
    return (dict(report.published), dict(report.consumed), dict(report.copied), drops,
            report.frames, report.done, report.total)


@pytest.fixture(scope='module')
def stereo_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Eight simulated frames; frame 5 lacks its right image."""
    path = tmp_path_factory.mktemp('parallel') / 'stereo'
    with BagWriter(path) as writer:
        for frame in simulate_stereo(STEREO):
            for topic, msg in frame_messages(frame):
                if frame.index == MISSING_RIGHT and topic == '/stereo/right/image_raw':
                    continue
                writer.write(topic, msg, frame.stamp_ns)
    return path


@pytest.fixture(scope='module')
def sl_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three structured-light sequences whose projector camera_info is recorded once, at
    the start (as a latched topic is): a worker that starts later must be primed with it."""
    folder = tmp_path_factory.mktemp('parallel_sl')
    write_structured_light_bag(folder / 'full', SL)
    path = folder / 'latched'
    seen_info = False
    with BagReader(folder / 'full') as reader, BagWriter(path) as writer:
        for m in reader.messages():
            if m.topic == '/sl/projector/camera_info':
                if seen_info:
                    continue
                seen_info = True
            writer.write(m.topic, m.data, m.timestamp, m.msgtype)
    (path / REFERENCE_FILE).write_bytes((folder / 'full' / REFERENCE_FILE).read_bytes())
    return path


def test_stereo_output_is_the_same_with_two_and_three_workers(
        stereo_bag: Path, tmp_path: Path, ros_env: dict[str, str]) -> None:
    one = process_bag(stereo_bag, tmp_path / 'one')
    expected = _messages(tmp_path / 'one')
    # the graph published for each of the 7 complete frames, and the lone left image of
    # frame 5 was counted when the next frame's pair completed
    assert one.published['/stereo/points2'] == STEREO.n_frames - 1
    assert sum(sum(c.values()) for c in one.drops.values()) >= 1
    for workers in (2, 3):
        report = process_bag(stereo_bag, tmp_path / f'w{workers}', workers=workers)
        assert _messages(tmp_path / f'w{workers}') == expected, workers
        assert _counts(report) == _counts(one), workers
        assert report.workers == workers


def test_the_bag_files_are_identical_apart_from_their_names(
        stereo_bag: Path, tmp_path: Path, ros_env: dict[str, str]) -> None:
    process_bag(stereo_bag, tmp_path / 'a' / 'out')
    process_bag(stereo_bag, tmp_path / 'b' / 'out', workers=2)
    for name in ('out.mcap', 'metadata.yaml'):
        assert (tmp_path / 'a' / 'out' / name).read_bytes() == \
            (tmp_path / 'b' / 'out' / name).read_bytes(), name
    assert not list(tmp_path.rglob('.depth-nodes-*'))  # hand-over files removed


def test_structured_light_sequences_and_a_latched_calibration_survive_the_cuts(
        sl_bag: Path, tmp_path: Path, ros_env: dict[str, str]) -> None:
    graph = small_sl_graph(sl_bag)
    one = process_bag(sl_bag, tmp_path / 'one', config=graph)
    assert one.published['/sl/depth'] == SL.sequences
    assert sum(sum(c.values()) for c in one.drops.values()) == 0
    # 3 workers cut the bag into 12 segments, most of them inside a sequence
    report = process_bag(sl_bag, tmp_path / 'three', config=graph, workers=3)
    assert _messages(tmp_path / 'three') == _messages(tmp_path / 'one')
    assert _counts(report) == _counts(one)


def test_ray_local_cluster_gives_the_same_bag(stereo_bag: Path, tmp_path: Path,
                                             ros_env: dict[str, str]) -> None:
    one = process_bag(stereo_bag, tmp_path / 'one')
    report = process_bag(stereo_bag, tmp_path / 'ray', workers=2, ray=True)
    assert _messages(tmp_path / 'ray') == _messages(tmp_path / 'one')
    assert _counts(report) == _counts(one)
    assert report.engine == 'Ray'


def test_segments_cover_the_bag_without_overlap() -> None:
    parts = segments(100, 199, 4)
    assert [p.start_ns for p in parts] == [None, 125, 150, 175]
    assert [p.stop_ns for p in parts] == [125, 150, 175, None]
    assert [p.last for p in parts] == [False, False, False, True]
    assert len(segments(5, 6, 10)) == 2  # never more segments than nanoseconds
    assert segments(5, 5, 3) == [segments(5, 5, 1)[0]]


def _result(index: int, seen: int, own_end: int, idle: set[int],
            outputs: dict[int, str] | None = None) -> SegmentResult:
    """A worker's result over ``seen`` messages whose outputs are named strings."""
    result = SegmentResult(index, [('/t', 1000 * index + i) for i in range(seen)], own_end,
                           idle)
    for local, name in (outputs or {}).items():
        result.outputs[local] = [('/out', 'std_msgs/msg/String', name.encode())]
    return result


def test_stitch_hands_over_at_the_first_common_idle_point() -> None:
    first = _result(0, 8, 5, {1, 6, 7}, {i: f'a{i}' for i in range(8)})
    # the second worker starts at global 5 and is idle after its locals 0 (global 5:
    # not idle in the first) and 2 (global 7: idle in both)
    second = _result(1, 6, 6, {0, 2, 4}, {i: f'b{i}' for i in range(6)})
    items = list(stitch(iter([first, second])))
    assert [i.index for i in items] == list(range(11))
    names = [o[2].decode() for i in items for o in i.outputs]
    assert names == ['a0', 'a1', 'a2', 'a3', 'a4', 'a5', 'a6', 'a7', 'b3', 'b4', 'b5']


def test_stitch_skips_a_segment_the_previous_worker_outlived() -> None:
    first = _result(0, 12, 4, {11}, {11: 'a11'})
    inside = _result(1, 3, 3, set())  # globals 4..6, inside the previous one's sequence
    last = _result(2, 6, 6, {4, 5}, {5: 'c5'})  # globals 7..12
    items = list(stitch(iter([first, inside, last])))
    assert [i.index for i in items] == list(range(13))
    assert [o[2] for i in items for o in i.outputs] == [b'a11', b'c5']
    # the last segment swallowed too: the first one ran to the end of the bag, and its
    # end-of-stream drops close the output
    first.drops[END] = [('/n', 'stream_ended', 2)]
    last = _result(2, 3, 3, set())  # globals 7..9, the last three of the bag
    items = list(stitch(iter([first, _result(1, 3, 3, set()), last])))
    assert [i.index for i in items] == [*range(12), END]
    assert items[-1].drops == [('/n', 'stream_ended', 2)]


def test_stitch_refuses_segments_without_a_common_idle_point() -> None:
    first = _result(0, 6, 4, {5})
    second = _result(1, 6, 6, {0, 3})  # global 4 and 7: never both idle
    with pytest.raises(BagError, match='use --workers 1'):
        list(stitch(iter([first, second])))


def test_stitch_ends_with_the_last_segments_end_of_stream() -> None:
    last = _result(0, 2, 2, set())
    last.drops[END] = [('/n', 'stream_ended', 1)]
    items = list(stitch(iter([last])))
    assert items[-1].index == END
    assert items[-1].drops == [('/n', 'stream_ended', 1)]


def test_serialize_is_deterministic() -> None:
    info = CameraInfo()
    info.header.frame_id = 'abc'  # 3 characters: padding follows the string
    info.distortion_model = 'plumb_bob'
    image = Image(encoding='mono8', height=1, width=3, step=3, data=[1, 2, 3])
    image.header.frame_id = 'left_camera_optical_frame'
    for msg in (info, image):
        first = serialize(msg)
        assert all(serialize(msg) == first for _ in range(20))
        # the same bytes as rclpy's, but for padding, which is zero
        plain = serialize_message(msg)
        assert len(plain) == len(first)
        assert all(ours == 0 for ours, theirs in zip(first, plain, strict=True)
                   if ours != theirs)
        assert deserialize_message(first, type(msg)) == msg


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_shows_frames_rate_and_eta_on_a_terminal_only() -> None:
    shown = _Tty()
    bar = Progress(200, shown)
    bar.update(0, force=True)
    bar.update(50, force=True)
    bar.close()
    assert '50/200 frames' in shown.getvalue()
    assert 'frames/s' in shown.getvalue()
    assert 'ETA' in shown.getvalue()
    assert shown.getvalue().endswith('\n')
    quiet = io.StringIO()
    bar = Progress(200, quiet)
    bar.update(50, force=True)
    bar.close()
    assert quiet.getvalue() == ''


def test_summary_line() -> None:
    report = ProcessReport(done=1800, total=1800, frames=200, seconds=40.0, workers=2)
    assert report.summary() == ('processed 200 frames (1800 of 1800 messages) in 40.0 s: '
                                '5.00 frames/s, 2 workers')
    ray = dataclasses.replace(report, workers=1, engine='Ray')
    assert ray.summary().endswith('1 worker on Ray')


def test_cli_prints_the_summary_and_refuses_bad_worker_options(
        tmp_path: Path, ros_env: dict[str, str]) -> None:
    done = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'o'),
                    '--workers', '2'], env=ros_env)
    assert done.returncode == 0, done.stderr
    assert 'processed 3 frames (27 of 27 messages)' in done.stdout
    assert '2 workers' in done.stdout
    bad = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'b'),
                   '--workers', '0'], env=ros_env)
    assert bad.returncode == 1
    assert bad.stderr.strip() == ('depth-nodes process: error: --workers must be at least 1, '
                                  'got 0')
    away = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'r'),
                    '--ray-address', '127.0.0.1:9'], env=ros_env)
    assert away.returncode == 1
    assert away.stderr.startswith('depth-nodes process: error: --ray-address 127.0.0.1:9: '
                                  'nothing answers there')
    assert len(away.stderr.strip().splitlines()) == 1
    assert not (tmp_path / 'b').exists()
    assert not (tmp_path / 'r').exists()


def _job(bag: Path, index: int, spill_dir: Path) -> SegmentJob:
    """A job over the whole bag (numbered ``index``) for the shipped stereo graph."""
    return SegmentJob(str(bag), load_graph_config(default_config_path()), {},
                      Segment(index, None, None), (), STEREO_INPUTS, str(spill_dir))


STEREO_INPUTS = ('/stereo/left/camera_info', '/stereo/left/image_raw',
                 '/stereo/right/camera_info', '/stereo/right/image_raw')


def _outputs(result: SegmentResult) -> list[tuple[str, str, bytes]]:
    return [out for item in stitch(iter([result])) for out in item.outputs]


@pytest.fixture
def worker_env(monkeypatch: pytest.MonkeyPatch, ros_env: dict[str, str]) -> None:
    """run_segment sets a worker's discovery and transport variables in its process (here
    the test's): each is restored after the test, set or not."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    for name in ('ROS_STATIC_PEERS', 'FASTDDS_BUILTIN_TRANSPORTS', *PROFILE_VARIABLES):
        value = os.environ.get(name)
        monkeypatch.setenv(name, value or '')  # recorded: put back as it was
        if value is None:
            monkeypatch.delenv(name)


def test_a_spill_file_is_written_over_by_the_next_segment(
        stereo_bag: Path, tmp_path: Path, worker_env: None) -> None:
    """A segment written out frees its spill file, and the next segment claims it and
    writes over it in place (a tenth of the kernel time of new pages): its outputs are read
    back whole, whatever the file held after them."""
    first = run_segment(_job(stereo_bag, 0, tmp_path))
    path = Path(first.spill or '')
    size = path.stat().st_size
    expected = _outputs(first)
    assert len(expected) > 10
    assert not path.exists()
    (free,) = tmp_path.iterdir()
    assert free.name == 'free-segment-0'
    with free.open('r+b') as stale:  # other bytes in place, and a longer tail
        stale.write(b'\xa5' * size * 2)
    job = _job(stereo_bag, 1, tmp_path)
    claim_spill(job)
    assert [p.name for p in tmp_path.iterdir()] == ['segment-1']
    second = run_segment(job)
    assert second.spill == str(tmp_path / 'segment-1')
    assert (tmp_path / 'segment-1').stat().st_size == 2 * size  # written over, in place
    assert _outputs(second) == expected


def test_a_worker_that_cannot_write_its_outputs_stops_in_one_line(
        stereo_bag: Path, tmp_path: Path, worker_env: None,
        capfd: pytest.CaptureFixture[str]) -> None:
    """A full disk under a worker's spill file stops the segment with one error, instead of
    each node taking it for a failure of its own frame (a traceback each)."""
    (tmp_path / 'segment-0').symlink_to('/dev/full')  # writes fail with ENOSPC
    with pytest.raises(BagError, match=r"^cannot write a worker's outputs to .*: No space "
                                       r'left on device$'):
        run_segment(_job(stereo_bag, 0, tmp_path))
    assert 'Traceback' not in capfd.readouterr().err


def test_workers_leave_sigterm_to_the_main_process() -> None:
    """SIGTERM sent to the whole process group (`timeout`, a service manager) killed the
    workers under the main process, which then failed with a traceback instead of closing
    the output with what was done: a worker now ignores it, and keeps working."""
    engine = LocalEngine(1)
    try:
        pid = engine._pool.submit(os.getpid).result(WAIT_S)
        os.kill(pid, signal.SIGTERM)
        assert engine._pool.submit(os.getpid).result(WAIT_S) == pid
    finally:
        engine.close()


def _numba_threads() -> int:
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]


def test_a_worker_has_its_share_of_the_cores() -> None:
    """numba reads NUMBA_NUM_THREADS when it is imported: the pool's initializer must set
    it before anything the worker imports brings numba in (the graph's modules do)."""
    engine = LocalEngine(2)
    try:
        threads = engine._pool.submit(_numba_threads).result(WAIT_S)
    finally:
        engine.close()
    assert threads == max(1, (os.cpu_count() or 1) // 2)


def test_a_worker_that_dies_is_one_error_line(stereo_bag: Path, tmp_path: Path,
                                              worker_env: None) -> None:
    """A worker killed (the out-of-memory killer, say) while it runs a segment: a
    BagError that `process` prints in one line (it was a BrokenProcessPool traceback)."""
    engine = LocalEngine(1)
    killed: list[int] = []

    def stop() -> bool:  # asked while the segment runs: the worker is killed then, once
        if not killed:
            for process in list(engine._pool._processes.values()):
                with contextlib.suppress(ProcessLookupError):  # (gone already)
                    os.kill(process.pid, signal.SIGKILL)
                killed.append(process.pid)
        return False

    try:
        with pytest.raises(BagError, match=r'^a worker process ended abruptly'):
            list(engine.map([_job(stereo_bag, 0, tmp_path)], stop))
    finally:
        engine.close()


_SHM_PROBE = """
import os, sys
import rclpy
from rclpy.context import Context
from depth_nodes.ros.dds import use_large_message_profile
use_large_message_profile()  # as every depth-nodes command does
if sys.argv[1] == 'worker':
    from depth_nodes.tools.bags.segments import worker_environment
    worker_environment()
from helpers import held_by
context = Context()
rclpy.init(args=[], context=context)
node = rclpy.create_node('probe', context=context)
print(sorted(held_by(os.getpid())))
node.destroy_node()
rclpy.shutdown(context=context)
"""


def test_a_worker_has_no_shared_memory_segment_to_leave_behind(
        ros_env: dict[str, str]) -> None:
    """A worker killed when a run stops (SIGINT, SIGTERM, an error) left its Fast DDS
    shared-memory segment in /dev/shm for good, 70 MB each. A worker routes its messages
    in-process: its participant now has no shared-memory transport, so no segment (the
    same probe without it shows the files one would be left with)."""
    import ast
    import subprocess
    import sys

    def new_files(mode: str) -> list[str]:
        out = subprocess.run([sys.executable, '-c', _SHM_PROBE, mode], env=ros_env,
                             capture_output=True, text=True, check=True)
        return list(ast.literal_eval(out.stdout.strip().splitlines()[-1]))

    assert any(not f.startswith('fastrtps_port') for f in new_files('plain'))
    assert new_files('worker') == []
