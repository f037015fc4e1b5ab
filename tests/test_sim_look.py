"""Cameras and look of the simulator: every object starts inside every camera's frame, the arm parks out of view,
the front camera is GenSim's, the render meshes are the collision meshes, colours stay distinguishable."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import load_script

from simeval.sim.core.objects import COLORS, make_object
from simeval.sim.core.world import OBS_CAMERAS, SCENE_VIEWS, TABLE_Z, TILE_RGB, World
from simeval.sim.robots.xarm import PARK, Arm, render_urdf
from simeval.sim.tasks.spec import suite_dir, SpecError, load_suite, sample_instance

SUITE = load_suite(suite_dir("gensim"))
MARGIN = 0.05  # of the frame's width/height: 3 pixels at 64x64
SUITE_COLORS = ("red", "green", "blue", "yellow", "purple", "orange", "cyan", "pink", "gray", "white", "brown",
                "black")


def _corners(obj, xy, yaw) -> np.ndarray:
    """The 8 corners of the object's bounding box at its sampled pose (a pile: its square, one particle high)."""
    sx, sy, sz = obj.size
    h = {"sphere": sx, "pile": 0.012, "zone": 0.002, "line": 0.002}.get(obj.shape, sz)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[xy[0] + c * dx - s * dy, xy[1] + s * dx + c * dy, TABLE_Z + z]
                     for dx in (-sx / 2, sx / 2) for dy in (-sy / 2, sy / 2) for z in (0.0, h)])


def _all_corners() -> tuple[np.ndarray, int]:
    pts, skipped = [], 0
    for spec in SUITE:
        for seed in range(100):
            try:
                inst = sample_instance(spec, seed)
            except SpecError:  # a layout that does not fit (sampling, not cameras): counted below
                skipped += 1
                continue
            pts += [_corners(o, *inst.poses[o.id]) for o in inst.objects]
    return np.concatenate(pts), skipped


@pytest.mark.parametrize("size", [(64, 64), (128, 128), (120, 160)])
def test_every_object_starts_inside_every_camera(size):
    """Seeds 0-99 of every task, every observation camera and scene view: each corner of each object's bounding
    box projects inside the frame with a margin (sampling only, no physics)."""
    pts, skipped = _all_corners()
    assert skipped <= 0.02 * len(SUITE) * 100
    h, w = size
    for cam in [*OBS_CAMERAS.values(), *SCENE_VIEWS]:
        uv, depth = cam.project(pts, size)
        assert (depth > 0).all(), cam.name
        inside = ((uv[:, 0] >= MARGIN * w) & (uv[:, 0] <= (1 - MARGIN) * w)
                  & (uv[:, 1] >= MARGIN * h) & (uv[:, 1] <= (1 - MARGIN) * h))
        assert inside.all(), f"{cam.name}: {int((~inside).sum())} corners outside the frame, e.g. {pts[~inside][0]}"


def test_projection_matches_the_renderer():
    """Camera.project agrees with what World.render draws: a small block's centre pixel shows the block."""
    with World() as w:
        col = w.c.createVisualShape(w.c.GEOM_BOX, halfExtents=[0.01] * 3, rgbaColor=[1, 0, 0, 1])
        body = w.c.createMultiBody(0, -1, col, [0.55, 0.18, 0.01])
        for cam in [*OBS_CAMERAS.values(), *SCENE_VIEWS]:
            seg = w.segmentation(cam, (96, 128))
            (u, v), = cam.project([[0.55, 0.18, 0.01]], (96, 128))[0]
            assert seg[int(v), int(u)] == body, cam.name


def test_front_camera_is_gensims():
    """RealSenseD415.CONFIG's front camera: eye (1, 0, 0.75), looking along (-1, 0, -1), vertical fov
    2*atan(240/450)."""
    cam = OBS_CAMERAS["front"]
    assert np.allclose(cam.eye, (1.0, 0.0, 0.75))
    d = np.subtract(cam.target, cam.eye)
    assert np.allclose(d / np.linalg.norm(d), np.array([-1.0, 0.0, -1.0]) / math.sqrt(2))
    assert cam.fov == pytest.approx(56.145, abs=1e-3)
    assert next(iter(OBS_CAMERAS)) == "front"
    assert SCENE_VIEWS[0].eye == cam.eye and SCENE_VIEWS[0].target == cam.target


GENSIM_CAMERAS = Path(__file__).resolve().parents[2] / "shared" / "gensim" / "cliport" / "tasks" / "cameras.py"


@pytest.mark.skipif(not GENSIM_CAMERAS.is_file(), reason="../shared/gensim is not beside this checkout")
def test_front_camera_draws_ravens_workspace_where_gensims_own_camera_does():
    """GenSim's front camera from GenSim's own file (RealSenseD415.CONFIG[0], loaded from the checkout) through the
    recipe of GenSim's Environment.render_camera (view from the rotation's look and up vectors, vertical fov from
    the focal length, at a square size with the focal length scaled as the gensim_own worker renders it): the
    corners of Ravens' workspace (x 0.25-0.75, y -0.5-0.5) and the robot's base land on the same pixels as with
    simeval's front camera, so the cameras are one; what differs in the side-by-side figure is what is drawn."""
    import pybullet as p

    gensim_cameras = load_script(GENSIM_CAMERAS)
    config = gensim_cameras.RealSenseD415.CONFIG[0]
    size = 128
    rotm = np.array(p.getMatrixFromQuaternion(config["rotation"])).reshape(3, 3)
    look, up = rotm @ [0, 0, 1], rotm @ [0, -1, 0]
    focal = config["intrinsics"][0] * size / config["image_size"][0]
    fov = math.degrees(2 * math.atan(size / 2 / focal))
    view = np.array(p.computeViewMatrix(config["position"], np.add(config["position"], look), up)).reshape(4, 4).T
    proj = np.array(p.computeProjectionMatrixFOV(fov, 1.0, *config["zrange"])).reshape(4, 4).T
    points = np.array([[0.25, -0.5, 0], [0.25, 0.5, 0], [0.75, -0.5, 0], [0.75, 0.5, 0], [0, 0, 0], [0.5, 0.2, 0.1]])
    clip = (proj @ view @ np.c_[points, np.ones(len(points))].T).T
    ndc = clip[:, :2] / clip[:, 3:]
    gensim_px = np.stack([(ndc[:, 0] + 1) / 2 * size, (1 - ndc[:, 1]) / 2 * size], axis=1)
    ours, _ = OBS_CAMERAS["front"].project(points, (size, size))
    assert np.allclose(ours, gensim_px, atol=0.05), np.c_[ours, gensim_px]
    assert ours[0, 1] == pytest.approx(64, abs=0.5)  # Ravens' far edge at mid-height, as in GenSim's own frames


def _arm_fraction(w: World, arm: Arm, cam, size=(64, 64)) -> float:
    seg = w.segmentation(cam, size)
    return float(np.isin(seg, [arm.body, arm.tool]).mean())


def test_park_pose_is_out_of_view():
    """At PARK the top camera sees none of the arm and the front camera sees it only behind its base, above the
    workspace tile's far edge (no workspace pixel covered)."""
    with World() as w:
        arm = Arm(w, "suction")
        for j, q in zip(arm.joints, PARK):
            w.c.resetJointState(arm.body, j, q)
        w.step(1)
        assert _arm_fraction(w, arm, OBS_CAMERAS["top"]) == 0.0
        assert _arm_fraction(w, arm, SCENE_VIEWS[3]) == 0.0
        # front: the workspace's far edge (x = 0.30) projects below every arm pixel
        seg = w.segmentation(OBS_CAMERAS["front"], (64, 64))
        rows = np.nonzero(np.isin(seg, [arm.body, arm.tool]).any(axis=1))[0]
        (_, far_edge_row), = OBS_CAMERAS["front"].project([[0.30, 0.0, 0.0]], (64, 64))[0]
        assert rows.max() < far_edge_row


def test_episode_ends_parked():
    """The oracle's episodes end with the arm at PARK (out of view: test_park_pose_is_out_of_view), recorded."""
    from simeval.sim.rollout import RecordSettings, run_episode

    spec = next(s for s in SUITE if s.name == "stack-two-blocks")
    ep = run_episode(spec, 0, RecordSettings(cameras=("top",), image_size=(32, 32), scene_view_size=(16, 16)))
    assert ep.success
    q = ep.state[-1][:6]
    assert abs(abs(q[0]) - math.pi) < 0.05 and np.allclose(q[1:], PARK[1:], atol=0.05)


def test_render_meshes_are_collision_meshes_and_look_the_same():
    """The render URDF's visuals are the collision meshes; the image of the arm barely changes."""
    text = open(render_urdf("collision")).read()
    assert "/visual/" not in text and text.count("_vhacd.obj") >= 14
    images = {}
    for mesh in ("visual", "collision"):
        with World() as w:
            Arm(w, "suction", render_mesh=mesh)
            w.step(1)
            images[mesh] = w.render(OBS_CAMERAS["front"], (64, 64), shadows=False).astype(int)
    diff = np.abs(images["visual"] - images["collision"]).max(axis=2)
    assert (diff > 60).mean() < 0.01  # under 1% of the pixels change noticeably


def test_colours_keep_their_names_and_stay_distinguishable():
    assert set(SUITE_COLORS) <= set(COLORS)
    used = {c for s in SUITE for o in s.objects for c in o.colors}
    assert used <= set(COLORS)
    rgb = {k: np.array(v) * 255 for k, v in COLORS.items()}
    closest = min(np.linalg.norm(rgb[a] - rgb[b]) for a, b in itertools.combinations(rgb, 2))
    assert closest >= 50  # 0-255 RGB; Ravens' palette: purple-gray 56 is its closest pair
    assert all(np.linalg.norm(v - np.array(TILE_RGB) * 255) >= 50 for v in rgb.values())  # visible on the tile


def test_objects_render_in_their_colours():
    """A block of each colour, rendered from the top camera on the tile, looks nearest its own colour."""
    with World() as w:
        rng = np.random.default_rng(0)
        from simeval.sim.core.objects import SimObject

        for name in COLORS:
            obj = make_object(w.c, SimObject("b", 0, "block", name, (0.06, 0.06, 0.04)), np.array([0.46, 0.0]), 0.0,
                              rng, TABLE_Z)
            img = w.render(OBS_CAMERAS["top"], (64, 64), shadows=False).astype(float)
            centre = img[30:34, 30:34].reshape(-1, 3).mean(axis=0)  # the block's top face (6 px wide)
            nearest = min(COLORS, key=lambda k: np.linalg.norm(centre - np.array(COLORS[k]) * 255))
            assert nearest == name, (name, centre.round())
            w.c.removeBody(obj.body_ids[0])
