"""The randomised content of the stereo test scene, deterministic from a seed.

Objects are placed by where they appear in the left rectified image (fractions of the
half field of view) and at which depth, so the layout looks the same at every image size;
texture periods and thin-structure widths are given in pixels at the object's depth and
converted with the focal length, so they stay a few pixels wide at every resolution.
Depths stay within about 0.85 m .. 8.5 m (the far corners of the slanted background).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from depth_nodes.sim import texture as tx
from depth_nodes.sim.scene import Box, Cylinder, Material, Primitive, Rect, Scene, Sphere

FloatArray = NDArray[np.float64]

#: Labels of the scene's primitives (several primitives may share one).
LABELS = (
    'background',
    'ground',
    'fronto',
    'slanted',
    'repetitive',
    'weak',
    'box',
    'sphere',
    'pole',
    'bar',
)


def rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> FloatArray:
    """Rotation about Y (yaw), then X (pitch), then Z (roll), degrees; R = Ry @ Rx @ Rz."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    out: FloatArray = ry @ rx @ rz
    return out


class _Builder:
    """Draws placements, colours and textures from one random generator."""

    def __init__(self, seed: int, index: int, focal_px: float, width: int, height: int):
        self.rng = np.random.default_rng([seed, 7])
        self.index = index
        self.f = focal_px
        self.xmax = 0.5 * width / focal_px
        self.ymax = 0.5 * height / focal_px
        self.prims: list[Primitive] = []

    def u(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def metres(self, px: float, z: float) -> float:
        """Length in metres that spans ``px`` pixels at depth ``z``."""
        return px * z / self.f

    def place(self, fx: float, fy: float, z: float, speed: float) -> FloatArray:
        """World point seen at (fx * xmax, fy * ymax) at depth z, plus its motion."""
        base = np.array(
            [
                (fx + self.u(-0.06, 0.06)) * self.xmax * z,
                (fy + self.u(-0.06, 0.06)) * self.ymax * z,
                z,
            ]
        )
        heading = self.u(0.0, 2.0 * np.pi)
        velocity = speed * np.array([np.cos(heading), self.u(-0.3, 0.3), 0.5 * np.sin(heading)])
        return base + self.index * velocity

    def material(
        self,
        kind: str,
        period_px: float,
        z: float,
        *,
        octaves: int = 4,
        mean: float = 0.5,
        contrast: float = 1.0,
    ) -> Material:
        """Random colour; texture period ``period_px`` pixels at depth ``z``."""
        colour = self.rng.uniform(0.5, 0.9, 3)
        seed = int(self.rng.integers(1 << 30))
        texture = tx.Texture(kind, self.metres(period_px, z), seed, octaves, contrast, mean)
        dark = (0.3 * colour[0], 0.3 * colour[1], 0.3 * colour[2])
        return Material(dark, (colour[0], colour[1], colour[2]), texture)

    def rect(
        self,
        label: str,
        mat: Material,
        centre: FloatArray,
        rot: FloatArray,
        half: tuple[float, float],
    ) -> None:
        # e1 x e2 = -Z (towards the cameras) before rotation.
        self.prims.append(Rect(label, mat, centre, rot @ [1.0, 0, 0], rot @ [0, -1.0, 0], half))


def build_scene(seed: int, index: int, focal_px: float, width: int, height: int) -> Scene:
    """The scene of frame ``index`` (objects move a few cm per frame).

    Args:
        seed: Scene seed; the same seed gives the same layout, colours and textures.
        index: Frame number (0-based), selects the positions of the moving objects.
        focal_px: Rectified focal length in pixels (sets texture periods and thin widths).
        width: Image width in pixels.
        height: Image height in pixels.

    Returns:
        The scene, primitives labelled with names from :data:`LABELS`.
    """
    b = _Builder(seed, index, focal_px, width, height)

    # Far slanted background plane, strong texture.
    z = b.u(5.9, 6.5)
    b.rect(
        'background',
        b.material(tx.NOISE, 32.0, z, octaves=4, mean=0.5, contrast=1.0),
        np.array([0.0, 0.0, z]),
        rotation(b.u(-15, 15), b.u(-8, 8)),
        (np.inf, np.inf),
    )

    # Slanted ground plane below the cameras; e1 x e2 = -Y (up).
    ground_y = b.u(1.1, 1.4)
    rot = rotation(0.0, b.u(-3, 3), b.u(-3, 3))
    b.prims.append(
        Rect(
            'ground',
            b.material(tx.NOISE, 40.0, 3.0, octaves=3, mean=0.5, contrast=0.9),
            [0.0, ground_y, 0.0],
            rot @ [1.0, 0, 0],
            rot @ [0, 0, 1.0],
        )
    )

    # Fronto-parallel strongly textured rectangle.
    z = b.u(3.6, 4.4)
    b.rect(
        'fronto',
        b.material(tx.NOISE, 32.0, z, mean=0.5, contrast=1.0),
        b.place(-0.55, -0.45, z, 0.03),
        np.eye(3),
        (0.2 * b.xmax * z, 0.25 * b.ymax * z),
    )

    # Strongly slanted checkerboard rectangle.
    z = b.u(3.0, 3.8)
    yaw = b.u(35, 55) * (1 if b.u(0, 1) < 0.5 else -1)
    b.rect(
        'slanted',
        b.material(tx.CHECKER, 14.0, z, mean=0.5, contrast=0.9),
        b.place(0.5, -0.45, z, 0.03),
        rotation(yaw, b.u(-15, 15)),
        (0.22 * b.xmax * z, 0.25 * b.ymax * z),
    )

    # Repetitive texture: vertical stripes with an 8..16 px period at their depth.
    z = b.u(4.4, 5.0)
    b.rect(
        'repetitive',
        b.material(tx.STRIPES, b.u(8, 16), z, mean=0.5, contrast=0.9),
        b.place(0.0, -0.6, z, 0.02),
        rotation(b.u(-8, 8)),
        (0.22 * b.xmax * z, 0.2 * b.ymax * z),
    )

    # Weakly textured region: smooth, very low contrast.
    z = b.u(3.8, 4.5)
    b.rect(
        'weak',
        b.material(tx.WEAK, 60.0, z, mean=0.5, contrast=0.05),
        b.place(-0.5, 0.25, z, 0.02),
        rotation(b.u(-10, 10)),
        (0.22 * b.xmax * z, 0.25 * b.ymax * z),
    )

    # A rotated box.
    z = b.u(2.3, 2.8)
    b.prims.append(
        Box(
            'box',
            b.material(tx.NOISE, 32.0, z, mean=0.5, contrast=1.0),
            b.place(0.45, 0.35, z, 0.03),
            rotation(b.u(25, 55), b.u(-10, 10), b.u(-10, 10)),
            [b.u(0.2, 0.3), b.u(0.15, 0.22), b.u(0.2, 0.3)],
        )
    )

    # Spheres: one mid-range, one near that moves faster.
    z = b.u(2.0, 2.6)
    b.prims.append(
        Sphere(
            'sphere',
            b.material(tx.NOISE, 32.0, z, mean=0.5, contrast=1.0),
            b.place(-0.15, 0.2, z, 0.03),
            b.u(0.22, 0.3),
        )
    )
    z = b.u(0.95, 1.15)
    b.prims.append(
        Sphere(
            'sphere',
            b.material(tx.NOISE, 32.0, z, mean=0.5, contrast=1.0),
            b.place(0.15, 0.0, z, 0.05),
            b.u(0.1, 0.14),
        )
    )

    # Thin vertical poles, 3..5 px wide at their depth, reaching below the ground.
    for fx in (-0.3, 0.2, 0.75):
        z = b.u(2.2, 4.5)
        radius = 0.5 * b.metres(b.u(3.0, 5.0), z)
        centre = b.place(fx, 0.0, z, 0.01)
        centre[1] = 0.0
        b.prims.append(
            Cylinder(
                'pole',
                b.material(tx.NOISE, 24.0, z, octaves=2, mean=0.5),
                centre,
                rotation(0, b.u(-3, 3), b.u(-3, 3)) @ [0, 1.0, 0],
                radius,
                6.0,
            )
        )

    # A thin, nearly horizontal bar, 4 px high at its depth.
    z = b.u(2.6, 3.0)
    b.prims.append(
        Box(
            'bar',
            b.material(tx.NOISE, 24.0, z, octaves=2, mean=0.5),
            b.place(-0.1, -0.2, z, 0.02),
            rotation(b.u(-5, 5), 0, b.u(-5, 5)),
            [0.3 * b.xmax * z, 0.5 * b.metres(4.0, z), 0.015],
        )
    )
    return Scene(tuple(b.prims))
