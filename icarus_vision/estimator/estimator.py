"""The relative gate pose estimator: detections + odometry -> where the next gate is, with covariance.

Each camera frame, every detection is checked (degenerate corners are rejected and counted), solved
by square PnP (both solutions kept), expressed in the odometry world frame through the camera mount
and the odometry pose, and the frame's detections are matched one-to-one to the gate tracks
(least total Mahalanobis distance, the two PnP solutions both tried, within the χ², direction and
range gates); each match updates that gate's Kalman filter. Between frames the filters only grow
their covariance. The next gate is switched when odometry crosses its estimated plane through its
opening (or vision moves the plane back past the drone).

* **map-aided**: one gate track per physical gate of a prior map (which may be displaced from the
  real gates); the next gate is the next passage of the map. Detections that fit no gate are
  outliers; several mutually consistent outliers re-initialise the nearest gate (a wrong prior).
* **map-free**: gate tracks are created from detections; the next gate is the nearest confirmed gate
  ahead of the drone that has not been passed.

The estimator never sees the true gates: only the prior map, the detections and odometry.
"""

from __future__ import annotations

import math
from collections import Counter, deque

import numpy as np

from icarus_vision.estimator.config import EstimatorConfig
from icarus_vision.estimator.estimate import NO_GATE_DISTANCE, NO_GATE_SIGMA, GateEstimate
from icarus_vision.estimator.filter import GateTrack, process_noise, update_tracks
from icarus_vision.estimator.fusion import match_detections, solve_detections
from icarus_vision.estimator.odometry import OdometryReading, check_odometry
from icarus_vision.estimator.pnp import GateMeasurement, wrap_axis
from icarus_vision.gate_detect.base import GateDetection
from icarus_vision.render.camera import Camera, project_points
from icarus_vision.sim.dynamics import quat_to_rot
from icarus_vision.sim.track import SAME_GATE_TOL, Gate, Track


class GateEstimator:
    """Filters detections into the next gate's relative position (see the module docstring).

    Args:
        camera: the camera model (K and mount) that took the images.
        config: estimator configuration.
        prior: the prior map (required in map-aided mode, ignored in map-free mode).
    """

    def __init__(
        self, camera: Camera, config: EstimatorConfig | None = None, prior: Track | None = None
    ) -> None:
        self.camera = camera
        self.config = config or EstimatorConfig()
        if self.config.mode == "map-aided" and prior is None:
            raise ValueError("map-aided mode needs a prior map (a Track); use mode='map-free'")
        self.prior = prior if self.config.mode == "map-aided" else None
        self._k = camera.K
        self._image_size = (camera.width, camera.height)
        self._r_body_cam = camera.r_body_cam
        self._q = process_noise(self.config.filter)
        self.reset()

    # -- state ----------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget everything (a new race)."""
        self.counts: Counter[str] = Counter()
        self.tracks: list[GateTrack] = []
        self.passage_gate: list[int] = []  # map-aided: gate track of each passage
        self.passage_yaw: list[float] = []  # map-aided: prior heading of each passage
        self.target = 0
        self._target_gate = -1  # map-free
        self._target_heading = 0.0
        self._last_passed = -1
        self._side: float | None = None  # the drone's side of the next gate's plane, last check
        self._passed: set[int] = set()
        self._odom: OdometryReading | None = None
        self._latest: OdometryReading | None = None  # the newest reading (passages)
        self._r_wb = np.eye(3)  # attitude of the latest odometry reading, body -> world
        self._rejected: deque = deque()
        if self.prior is not None:
            self._load_prior(self.prior)

    def _load_prior(self, prior: Track) -> None:
        c = self.config
        cov = np.diag([c.map_sigma_m**2] * 3 + [math.radians(c.map_yaw_sigma_deg) ** 2])
        for g in prior.passages:
            found = [
                i
                for i, tr in enumerate(self.tracks)
                if np.linalg.norm(tr.pos - np.asarray(g.pos)) < SAME_GATE_TOL
            ]
            if not found:
                self.tracks.append(GateTrack(np.array(g.pos), g.yaw, cov, g.size, 0.0, True))
                found = [len(self.tracks) - 1]
            self.passage_gate.append(found[0])
            self.passage_yaw.append(g.yaw)

    # -- public API ---------------------------------------------------------------------------
    def predict(self, odom: OdometryReading) -> GateEstimate:
        """Advance to a new odometry reading without a camera frame.

        Raises:
            ValueError: non-finite odometry.
        """
        self._advance(odom)
        return self._estimate(measured=False)

    def update(self, odom: OdometryReading, detections: list[GateDetection]) -> GateEstimate:
        """Advance to ``odom`` (the pose at which the image was taken) and fuse its detections.

        Raises:
            ValueError: non-finite odometry.
        """
        self._advance(odom)
        measured = self._fuse(odom, detections)
        return self._estimate(measured=measured)

    def gate_after_position(self) -> np.ndarray | None:
        """Map-aided: the estimated world position (3,) of the gate after the next one (the last
        gate repeats at the end of the course); None in map-free mode."""
        if self.config.mode != "map-aided" or not self.passage_gate:
            return None
        j = min(self.target + 1, len(self.passage_gate) - 1)
        return self.tracks[self.passage_gate[j]].pos.copy()

    def gate_after_yaw(self) -> float | None:
        """Map-aided: the estimated passage heading (rad) of the gate after the next one (the last
        gate repeats at the end of the course); None in map-free mode."""
        if self.config.mode != "map-aided" or not self.passage_gate:
            return None
        j = min(self.target + 1, len(self.passage_gate) - 1)
        return self._heading(self.passage_gate[j], self.passage_yaw[j])

    def passage_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Map-aided: every passage's estimated world position (M, 3) and passage heading (M,),
        rad, as vision has corrected the prior so far; None in map-free mode."""
        if self.config.mode != "map-aided" or not self.passage_gate:
            return None
        pos = np.array([self.tracks[g].pos for g in self.passage_gate])
        yaw = np.array(
            [self._heading(g, y) for g, y in zip(self.passage_gate, self.passage_yaw, strict=True)]
        )
        return pos, yaw

    # -- prediction and gate switching ---------------------------------------------------------
    def _advance(self, odom: OdometryReading) -> None:
        check_odometry(odom)
        prev = self._odom
        dt = 0.0 if prev is None else max(odom.t - prev.t, 0.0)
        if dt > 0:
            q_dt = np.diag(self._q * dt)
            for tr in self.tracks:
                tr.add_noise(q_dt)
        # Passages are checked along time only: an update at an older image's pose (latency)
        # must not look like flying back through the gate just passed (a hairpin's next passage).
        last = self._latest
        if last is None or odom.t > last.t:
            if last is not None:
                self._check_passage(last.pos, odom.pos)
            self._latest = odom
        self._odom = odom
        self._r_wb = quat_to_rot(odom.quat[None] / np.linalg.norm(odom.quat))[0]
        if self.config.mode == "map-free":
            self._prune(odom.t)
            self._select_target(odom)

    def _target_track(self) -> int:
        if self.config.mode == "map-aided":
            return self.passage_gate[min(self.target, len(self.passage_gate) - 1)]
        return self._target_gate

    def _heading(self, gate: int, ref: float | None = None) -> float:
        """Passage heading of a gate track: its axis turned toward the expected direction ``ref``
        (default: the target passage's); map-aided, within ``map_yaw_limit_sigmas`` of it."""
        if ref is None:
            ref = (
                self.passage_yaw[min(self.target, len(self.passage_yaw) - 1)]
                if self.config.mode == "map-aided"
                else self._target_heading
            )
        turn = wrap_axis(self.tracks[gate].mean[3] - ref)
        if self.config.mode == "map-aided":
            limit = math.radians(self.config.map_yaw_sigma_deg * self.config.map_yaw_limit_sigmas)
            turn = min(max(turn, -limit), limit)
        return float(ref + turn)

    def _check_passage(self, p0: np.ndarray, p1: np.ndarray) -> None:
        """Count a passage when odometry goes from before the next gate's estimated plane to
        behind it, through its opening.

        The plane moves as vision corrects the gate: an update that shifts it back past the drone
        between two checks would leave the drone behind the plane without ever crossing it, and
        the estimator chasing a gate already flown through. So "before" is also the side of the
        previous check, under the estimate of that moment, when the plane has moved by less than
        half the gate's size since.
        """
        gi = self._target_track()
        if gi < 0 or (self.config.mode == "map-aided" and self.target >= len(self.passage_gate)):
            return
        tr = self.tracks[gi]
        yaw = self._heading(gi)
        n = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        s0, s1 = float((p0 - tr.pos) @ n), float((p1 - tr.pos) @ n)
        was_before = s0 < 0.0 or (
            self._side is not None and self._side < 0.0 and s0 < 0.5 * tr.size
        )
        self._side = s1
        if not (was_before and s1 >= 0.0):
            return
        frac = s0 / (s0 - s1) if s0 < 0.0 else 0.0
        cross = p0 + (p1 - p0) * frac - tr.pos
        reach = 0.5 * tr.size * (1.0 + self.config.filter.passage_margin)
        if np.max(np.abs(cross - (cross @ n) * n)) > reach:
            return
        self.counts["passages"] += 1
        self.target += 1
        self._side = None
        if self.config.mode == "map-free":
            self._passed.add(gi)
            self._last_passed = gi
            self._target_gate = -1

    def _prune(self, t: float) -> None:
        """Map-free: drop gates seen once and never confirmed within a second."""
        hits = self.config.filter.confirm_hits
        keep = [
            i
            for i, tr in enumerate(self.tracks)
            if tr.hits >= hits or t - tr.created_t < 1.0 or i == self._target_gate
        ]
        # Two tracks of one gate (its first sightings were too far apart): keep the older one.
        for a in list(keep):
            for b in keep:
                if b < a and np.linalg.norm(self.tracks[a].pos - self.tracks[b].pos) < 0.5 * (
                    self.tracks[a].size
                ):
                    if a != self._target_gate:
                        keep.remove(a)
                    break
        if len(keep) == len(self.tracks):
            return
        remap = {old: new for new, old in enumerate(keep)}
        self.tracks = [self.tracks[i] for i in keep]
        self._target_gate = remap.get(self._target_gate, -1)
        self._last_passed = remap.get(self._last_passed, -1)
        self._passed = {remap[i] for i in self._passed if i in remap}

    def _select_target(self, odom: OdometryReading) -> None:
        """Map-free: the nearest confirmed gate ahead that has not been passed (sticky)."""
        fwd = self._r_wb[:, 0]
        fwd = np.array([fwd[0], fwd[1], 0.0]) / max(math.hypot(fwd[0], fwd[1]), 1e-9)
        best, best_d = -1, math.inf
        pool = [i for i, tr in enumerate(self.tracks) if tr.hits >= self.config.filter.confirm_hits]
        if pool and all(i in self._passed for i in pool):
            self._passed = {self._last_passed}  # a new lap: every gate but the last is ahead again
        for i in pool:
            d = self.tracks[i].pos - odom.pos
            dist = float(np.linalg.norm(d))
            if i in self._passed or d @ fwd <= 0.0 or dist < 0.3:
                continue
            if dist < best_d:
                best, best_d = i, dist
        cur = self._target_gate
        if best < 0 or best == cur:
            return
        if cur >= 0 and best_d > 0.7 * float(np.linalg.norm(self.tracks[cur].pos - odom.pos)):
            return
        self._target_gate = best
        self._side = None
        d = self.tracks[best].pos - odom.pos
        axis = self.tracks[best].mean[3]
        # Face away from the drone: the passage direction points from the drone through the gate.
        self._target_heading = (
            axis if math.cos(axis) * d[0] + math.sin(axis) * d[1] >= 0 else axis + math.pi
        )

    # -- measurement update --------------------------------------------------------------------
    def _fuse(self, odom: OdometryReading, detections: list[GateDetection]) -> bool:
        """Update the gate tracks with a frame's detections (see :mod:`.fusion`); whether the
        next gate was among them."""
        r_wc, t_wc = self._r_wb @ self._r_body_cam, odom.pos
        size = self._size_guess()
        if detections:
            self.counts["detections"] += len(detections)
        floor = self.config.measurement.min_score
        if floor > 0 and detections:
            sure = [d for d in detections if d.score >= floor]
            self.counts["rejected_low_score"] += len(detections) - len(sure)
            detections = sure
        sols, reasons = solve_detections(
            detections,
            self._k,
            self._image_size,
            r_wc,
            t_wc,
            self.config.measurement,
            size,
            self.camera.undistort if self.camera.distorted else None,
        )
        self.counts.update(f"rejected_{r}" for r in reasons if r is not None)
        if sols is None:
            return False
        pairs, unmatched, left = match_detections(
            sols, self.tracks, size, r_wc, t_wc, self.config, odom.t
        )
        self.counts["duplicates"] += left
        # What match_detections neither matched, kept as outliers nor left over lay under the floor.
        self.counts["below_ground"] += len(sols.distance) - len(pairs) - len(unmatched) - left
        chosen = {ti: m for _, ti, m in pairs}  # track -> its measurement
        if chosen:
            update_tracks([self.tracks[ti] for ti in chosen], list(chosen.values()), odom.t)
            self.counts["accepted"] += len(chosen)
        for m in unmatched:
            self._unmatched(m, odom.t, r_wc, t_wc)
        return self._target_track() in chosen

    def _size_guess(self) -> float:
        return (
            self.tracks[0].size if self.prior is not None and self.tracks else self.config.gate_size
        )

    def _in_view(self, track: GateTrack, r_wc: np.ndarray, t_wc: np.ndarray) -> bool:
        """Whether the whole opening of ``track``'s estimate lies in front of the camera and
        inside the image: where vision would see the gate if the map were right."""
        gate = Gate(tuple(track.pos), math.degrees(track.mean[3]), track.size)
        pixels, _ = project_points(self._k, (gate.corners() - t_wc) @ r_wc)
        return bool(self.camera.in_image(self.camera.distort(pixels)).all())

    def _unmatched(self, m: GateMeasurement, t: float, r_wc: np.ndarray, t_wc: np.ndarray) -> None:
        """A detection no gate explains: an outlier, a wrong prior, or (map-free) a new gate."""
        fc = self.config.filter
        if self.config.mode == "map-free":
            cov = m.cov * fc.new_gate_sigma_scale**2
            self.tracks.append(GateTrack(m.pos, m.yaw, cov, self.config.gate_size, t, False))
            self.tracks[-1].hits = 1
            self.counts["new_gates"] += 1
            return
        self.counts["outliers"] += 1
        self._rejected.append((t, m))
        while self._rejected and t - self._rejected[0][0] > fc.reinit_window_s:
            self._rejected.popleft()
        agree = [
            o
            for _, o in self._rejected
            if (d := o.pos - m.pos) @ np.linalg.solve(o.cov[:3, :3] + m.cov[:3, :3], d)
            <= fc.gate_chi2
        ]
        if len(agree) < fc.reinit_count:
            return
        dists = [float(np.linalg.norm(tr.pos - m.pos)) for tr in self.tracks]
        ti = int(np.argmin(dists))
        # Only a gate that vision has confirmed less often than it has contradicted it lately,
        # though the map puts it in view, is moved: a persistent false detection next to a gate
        # that is being measured well, or next to one the camera cannot see (just flown through,
        # behind or beside the drone), stays an outlier. Nor is a gate of the map moved beyond
        # ``map_limit_sigmas`` of where the map has it.
        tr = self.tracks[ti]
        if (
            dists[ti] <= fc.reinit_radius_m
            and not (tr.from_map and np.linalg.norm(m.pos - tr.anchor) > self.config.map_limit_m)
            and len(agree) > fc.reinit_vote * tr.hits_since(t - fc.reinit_window_s)
            and self._in_view(tr, r_wc, t_wc)
        ):
            tr.reinit(m, t)
            self.counts["reinit"] += 1
            self._rejected.clear()

    # -- output ---------------------------------------------------------------------------------
    def _estimate(self, measured: bool) -> GateEstimate:
        odom, r_wb = self._odom, self._r_wb
        gi = self._target_track()
        if gi < 0:
            rel_body = np.array([NO_GATE_DISTANCE, 0.0, 0.0])
            cov_body = NO_GATE_SIGMA**2 * np.eye(3)
            rel_world = r_wb @ rel_body
            return GateEstimate(
                odom.t, self.target, -1, False, rel_world, rel_body, cov_body.copy(), cov_body,
                odom.pos + rel_world, math.atan2(r_wb[1, 0], r_wb[0, 0]), math.pi, False, math.inf,
            )  # fmt: skip
        tr = self.tracks[gi]
        rel_world = tr.pos - odom.pos
        cov_world = tr.cov[:3, :3].copy()
        return GateEstimate(
            t=odom.t,
            target=self.target,
            gate=gi,
            valid=True,
            rel_world=rel_world,
            rel_body=r_wb.T @ rel_world,
            cov_world=cov_world,
            cov_body=r_wb.T @ cov_world @ r_wb,
            gate_pos=tr.pos.copy(),
            yaw=self._heading(gi),
            yaw_sigma=math.sqrt(tr.cov[3, 3]),
            measured=measured,
            since_seen_s=odom.t - tr.last_hit_t,
            size=tr.size,
        )
