"""The depth filter on real photographs: the stereo graph's depth of Middlebury 2003 Teddy and
Cones (test/data), one frame each, before and after the filter's single-frame stages,
scored as disparity (f B / Z) against the ground truth over the non-occluded pixels.

    T=test/data/middlebury2003/teddy   # and cones
    depth-nodes import-pair $T/im2.png $T/im6.png /tmp/teddy_in --gt $T/disp2.pgm \\
        --gt-scale 4 --gt-right $T/disp6.pgm
    depth-nodes process /tmp/teddy_in /tmp/teddy_out --params config/disparity_64.yaml
    python docs/experiments/depth_filter_real_pairs.py /tmp/teddy_out /tmp/cones_out
"""

import sys

import numpy as np

from depth_nodes.core.depth_filter import DepthFilter, DepthFilterParams, stereo_sigma
from depth_nodes.core.depth_image import to_metres
from depth_nodes.core.geometry import intrinsics
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader

TOPICS = ['/stereo/depth', '/stereo/left/camera_info', '/stereo/right/camera_info',
          '/stereo/left/disparity_gt', '/stereo/left/occlusion_gt']
VERSIONS = [('depth_filter defaults', DepthFilterParams()),
            ('flying pixels only', DepthFilterParams(spatial=False, temporal=False)),
            ('spatial only', DepthFilterParams(flying_gap=0.0, temporal=False))]


def main(bags: list[str]) -> None:
    for bag in bags:
        with BagReader(bag) as reader:
            m = {x.topic: x.deserialize() for x in reader.messages(TOPICS)}
        depth = to_metres(image_to_array(m[TOPICS[0]]), m[TOPICS[0]].encoding)
        camera = intrinsics(camera_info_to_model(m[TOPICS[1]]), depth.shape)
        f_b = -np.asarray(m[TOPICS[2]].p).reshape(3, 4)[0, 3]
        truth = read_disparity(m[TOPICS[3]]).disparity
        valid = np.isfinite(truth) & (truth > 0) & ~(image_to_array(m[TOPICS[4]]) > 0)

        sigma = stereo_sigma(depth, camera.fx, f_b / camera.fx, 0.25)
        versions = [('the stereo graph\'s depth', depth)] + [
            (name, DepthFilter().process(depth, camera, params, sigma=sigma).depth)
            for name, params in VERSIONS]
        for name, z in versions:
            with np.errstate(divide='ignore', invalid='ignore'):
                d = f_b / z
            has = np.isfinite(d) & valid
            bad1 = np.mean(np.abs(d[has] - truth[has]) > 1)
            print(f'{bag}: {name:26s} density {has.sum() / valid.sum():.3f}  bad-1 '
                  f'{100 * bad1:.2f} %')


if __name__ == '__main__':
    main(sys.argv[1:])
