# Two commands on a fresh machine: `make demo` and `make test`. Both create ./.venv.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_OUT := out/demo
# pytest's workers (pytest-xdist; each test file on one of them); WORKERS=0: no workers
WORKERS ?= 2

.PHONY: venv test check lint typecheck unit demo bags clean

venv: $(STAMP)

$(STAMP): setup.py setup.cfg requirements/constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --disable-pip-version-check 'pip==23.2.1' 'setuptools==65.5.0' 2>&1 | grep -v 'is ignored' || true
	$(BIN)/python -m pip install -q --disable-pip-version-check -c requirements/constraints.txt -e '.[ros,dev,cluster,realsense,train,open3d]' 2>&1 | grep -v 'is ignored' || true
	# a venv made before the switch to the contrib build holds both wheels, which share cv2/
	if $(BIN)/python -m pip show -q opencv-python-headless >/dev/null 2>&1; then \
	  $(BIN)/python -m pip uninstall -y -q opencv-python-headless && \
	  $(BIN)/python -m pip install -q --force-reinstall --no-deps -c requirements/constraints.txt opencv-contrib-python-headless; fi
	$(BIN)/python -c 'import depth_nodes, rclpy, cv2, numba, rosbags, ray, jax; cv2.structured_light; from depth_nodes.tools.evaluation.librealsense import load_pyrealsense; load_pyrealsense(); from depth_nodes.tools.train.photos import load_photos; load_photos(); from depth_nodes.tools.evaluation.open3d_fusion import load_open3d; load_open3d()'
	touch $(STAMP)

lint: venv
	$(BIN)/ruff check .

typecheck: venv
	$(BIN)/mypy

unit: venv
	$(BIN)/python -m pytest -n $(WORKERS) --dist loadfile

test: lint typecheck unit

# The fast tier, for every edit: ruff and the tests not marked slow (about a minute and a
# half on two cores). `make test` is the whole suite, and what CI runs.
check: venv
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -m 'not slow' -n $(WORKERS) --dist loadfile

# The shipped stereo graph on the bundled simulator bag and on a real pair with ground
# truth (Middlebury 2003 Teddy, test/data), each scored beside OpenCV's StereoSGBM (Teddy
# also beside the matcher with each matching cost, census and learned); the depth filter
# on the bundled depth camera's bag, beside librealsense's filters; the same bag fused into
# a mesh (config/fusion_pipeline.yaml), scored against the exact surface, written as PLY
# with a preview picture.
TEDDY := test/data/middlebury2003/teddy
demo: venv
	rm -rf $(DEMO_OUT)
	$(BIN)/depth-nodes process bags/stereo_vga $(DEMO_OUT)/stereo_vga_out
	$(BIN)/depth-nodes eval $(DEMO_OUT)/stereo_vga_out --previews $(DEMO_OUT)/previews
	$(BIN)/depth-nodes import-pair $(TEDDY)/im2.png $(TEDDY)/im6.png $(DEMO_OUT)/teddy \
	  --gt $(TEDDY)/disp2.pgm --gt-scale 4 --gt-right $(TEDDY)/disp6.pgm
	$(BIN)/depth-nodes process $(DEMO_OUT)/teddy $(DEMO_OUT)/teddy_out \
	  --params config/disparity_64.yaml
	$(BIN)/depth-nodes eval $(DEMO_OUT)/teddy_out --previews $(DEMO_OUT)/previews_teddy \
	  --matching-costs census,learned,census+learned
	$(BIN)/depth-nodes process bags/depth_moving_camera $(DEMO_OUT)/depth_filter_out \
	  --config config/depth_filter_pipeline.yaml
	$(BIN)/depth-nodes eval $(DEMO_OUT)/depth_filter_out --librealsense
	$(BIN)/depth-nodes process bags/depth_moving_camera $(DEMO_OUT)/fusion_out \
	  --config config/fusion_pipeline.yaml
	$(BIN)/depth-nodes eval $(DEMO_OUT)/fusion_out
	$(BIN)/depth-nodes export-mesh $(DEMO_OUT)/fusion_out $(DEMO_OUT)/fusion_mesh.ply \
	  --preview $(DEMO_OUT)/fusion_mesh.png

# Regenerate the committed synthetic bags (deterministic from their seeds).
bags: venv
	$(BIN)/depth-nodes generate bags --preset all --force

clean:
	rm -rf $(VENV) out build install log *.egg-info
