from __future__ import annotations

import numpy as np

from icarus_vision.render.camera import Camera
from icarus_vision.render.labels import HIDDEN, OUTSIDE, VISIBLE, frame_labels
from icarus_vision.render.scene import Scene
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.track import Gate, Track

LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


def test_corner_order_approaching_along_x(one_gate_scene):
    frame = one_gate_scene.render(EYE, LEVEL)
    (lab,) = frame_labels(one_gate_scene, frame, EYE, LEVEL)
    tl, tr, br, bl = lab.corners_px
    assert tl[0] < tr[0] and bl[0] < br[0]  # left is left on screen
    assert tl[1] < bl[1] and tr[1] < br[1]  # top is up on screen
    assert list(lab.visibility) == [VISIBLE] * 4
    assert lab.gate_id == 0 and lab.passage == 0 and abs(lab.distance - 4.0) < 1e-9
    np.testing.assert_allclose(lab.t_cam_gate, [0.0, 0.0, 4.0], atol=1e-9)
    np.testing.assert_allclose(
        lab.r_cam_gate[:, 0], [0.0, 0.0, 1.0], atol=1e-9
    )  # passage = forward
    x, y, w, h = lab.bbox
    assert x < tl[0] and y < tl[1] and x + w > br[0] and y + h > br[1]


def test_visible_corners_lie_on_gate_pixels():
    rng = np.random.default_rng(1)
    gates = tuple(
        Gate((6.0 * (i + 1), rng.uniform(-2, 2), 2.0), rng.uniform(-30, 30)) for i in range(3)
    )
    track = Track("three", gates)
    with Scene(track, Camera()) as scene:
        checked = 0
        for _ in range(6):
            pos = np.array([rng.uniform(-2, 3), rng.uniform(-1, 1), rng.uniform(1.0, 3.0)])
            quat = rpy_to_quat(rng.uniform([-0.5, -0.2, -0.3], [0.5, 0.4, 0.3])[None])[0]
            frame = scene.render(pos, quat)
            for lab in frame_labels(scene, frame, pos, quat):
                body = scene.gate_bodies[lab.gate_id]
                for (u, v), flag in zip(lab.corners_px, lab.visibility, strict=True):
                    if flag == VISIBLE:
                        ui, vi = int(round(u)), int(round(v))
                        win = frame.seg[max(vi - 2, 0) : vi + 3, max(ui - 2, 0) : ui + 3]
                        assert (win == body).any()
                        checked += 1
                    if flag == OUTSIDE:
                        assert not scene.camera.in_image(np.array([u, v]))
        assert checked >= 8


def test_gate_behind_camera_gives_no_label():
    track = Track("behind", (Gate((-4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    with Scene(track, Camera(hfov_deg=120.0)) as scene:
        frame = scene.render(EYE, LEVEL)
        assert frame_labels(scene, frame, EYE, LEVEL) == []


def test_gate_seen_from_its_exit_side_gives_no_label():
    track = Track("back", (Gate((4.0, 0.0, 2.0), 180.0),), start_pos=(0.0, 0.0, 0.2))
    with Scene(track, Camera(uptilt_deg=0.0)) as scene:
        frame = scene.render(EYE, LEVEL)
        assert (frame.seg == scene.gate_bodies[0]).any()
        assert frame_labels(scene, frame, EYE, LEVEL) == []


def test_gate_seen_from_behind_is_labelled_with_back_views():
    track = Track("back", (Gate((4.0, 0.0, 2.0), 180.0),), start_pos=(0.0, 0.0, 0.2))
    with Scene(track, Camera(uptilt_deg=0.0)) as scene:
        frame = scene.render(EYE, LEVEL)
        (lab,) = frame_labels(scene, frame, EYE, LEVEL, back_views=True)
    assert lab.from_behind and lab.passage is None and lab.gate_id == 0
    # Named as seen from this side: TL top-left on screen, like any gate approached head-on.
    tl, tr, br, bl = lab.corners_px
    assert tl[0] < tr[0] and bl[0] < br[0] and tl[1] < bl[1] and tr[1] < br[1]
    assert list(lab.visibility) == [VISIBLE] * 4
    np.testing.assert_allclose(lab.r_cam_gate[:, 0], [0.0, 0.0, 1.0], atol=1e-9)  # x: away


def test_gate_flown_both_ways_is_labelled_from_either_side():
    track = Track("twice", (Gate((4.0, 0.0, 2.0)), Gate((4.0, 0.0, 2.0), 180.0)))
    back = np.array([8.0, 0.0, 2.0])
    turned = rpy_to_quat(np.array([[0.0, 0.0, np.pi]]))[0]
    with Scene(track, Camera(uptilt_deg=0.0)) as scene:
        for pos, quat, passage in ((EYE, LEVEL, 0), (back, turned, 1)):
            (lab,) = frame_labels(scene, scene.render(pos, quat), pos, quat)
            assert lab.gate_id == 0 and lab.passage == passage
            assert lab.corners_px[0, 0] < lab.corners_px[1, 0]  # TL left of TR either way


def test_box_in_front_of_a_corner_hides_only_that_corner(one_gate_scene):
    scene = one_gate_scene
    # The TL corner is at world (4, 0.5, 2.5); a 20 cm box 1 m in front of it covers it.
    box = scene.add_box((3.0, 0.5 * 3 / 4, 2.0 + 0.5 * 3 / 4), (0.05, 0.1, 0.1))
    frame = scene.render(EYE, LEVEL)
    (lab,) = frame_labels(scene, frame, EYE, LEVEL)
    assert list(lab.visibility) == [HIDDEN, VISIBLE, VISIBLE, VISIBLE]
    u, v = np.round(lab.corners_px[0]).astype(int)
    assert frame.seg[v, u] == box


def test_partly_out_of_frame_gate_flags_outside_corners():
    track = Track("edge", (Gate((3.0, 2.9, 2.0)),))
    with Scene(track, Camera(uptilt_deg=0.0)) as scene:
        frame = scene.render(EYE, LEVEL)
        (lab,) = frame_labels(scene, frame, EYE, LEVEL)
        # Left corners at u = 159.5 - 160 * 3.4 / 3 < 0, right ones at 159.5 - 160 * 2.4 / 3 > 0.
        assert list(lab.visibility) == [OUTSIDE, VISIBLE, VISIBLE, OUTSIDE]
        assert lab.bbox[0] == -0.5
