"""Rerun logging of a bimgraph run: what the backend believed at every keyframe, and why.

`RerunViewer` receives one call per keyframe (plus face-state changes) and logs, on the
`keyframe` sequence timeline and the `stamp` time timeline: the BIM faces as meshes coloured
by state, the raw trajectory mapped by the initial alignment and the corrected one, the
camera with its frustum and depth image, the detected planes, the association lines, the
extrinsic, and the time series. It never touches the estimator: it is handed plain poses,
plane observations and face ids.

Logging is buffered: `keyframe` only appends a record; now and then the records are turned
into arrays and sent with one `send_columns` call per entity. One `rr.log` call costs about
200 us (rerun-sdk 0.41, measured here), more than a backend step's budget for logging, and a
flush has a fixed cost per entity, so flushes are spaced by at least
`ViewerConfig.flush_seconds` and by enough that they take at most `flush_budget` of the
wall time.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import ViewerConfig
from bimgraph.evaluation.metrics import T_MAX_DIFF_S, nearest_stamps
from bimgraph.geometry import sigmas_in_B
from bimgraph.sequence.format import Camera, PlaneObservation
from bimgraph.viewer import blueprint as bp
from bimgraph.viewer.drawing import angles_deg, closed_rings, plane_centre_C, project, segments
from bimgraph.viewer.meshes import face_mesh

# Stamps beyond this (1973 in Unix time) are wall-clock times, smaller ones seconds since start.
_UNIX_STAMP_MIN = 1e8


class FaceState(IntEnum):
    """Display state of a BIM face; a higher state wins over a lower one."""

    UNOBSERVED = 0
    OBSERVED = 1
    ASSOCIATED = 2
    CONTESTED = 3  # one of the walls of a contest: off plan or not, the data barely tell
    DEVIATING = 4


def face_entity(face_id: str) -> str:
    import rerun as rr

    return f"{bp.FACES}/{rr.escape_entity_path_part(face_id)}"


@dataclass
class _Record:
    index: int
    stamp: float
    T_S_C: np.ndarray
    T_B_C: np.ndarray
    T_B_S: np.ndarray
    cov_T_B_S: np.ndarray | None
    planes: Sequence[PlaneObservation]
    plane_faces: Sequence[str | None]
    associations: int | None
    latency_s: float | None
    depth: np.ndarray | None


class RerunViewer:
    """Logs a run into a Rerun recording stream (see `bimgraph.viewer.recording.open_recording`).

    `T_B_S_initial` is the initial (manual) alignment that maps the raw front-end trajectory
    into B. `T_B_C_truth` (a reference trajectory's stamps and poses: each keyframe takes the
    one nearest its stamp, `nearest_stamps`) and `T_B_S_truth` turn on the error series and
    the ground-truth trail. Call `keyframe` once per keyframe in order,
    `set_face_state` when the backend's belief about a face changes, and `close` at the end.
    """

    def __init__(self, recording, plane_map: PlaneMap, T_B_S_initial: np.ndarray, *, camera: Camera | None = None,
                 T_B_C_truth: tuple[np.ndarray, np.ndarray] | None = None, T_B_S_truth: np.ndarray | None = None,
                 config: ViewerConfig | None = None):
        import rerun as rr

        self.rr = rr
        self.recording = recording
        self.cfg = config or ViewerConfig()
        self.plane_map = plane_map
        self.T_B_S_initial = np.asarray(T_B_S_initial, dtype=float)
        self.T_B_C_truth = T_B_C_truth or (np.zeros(0), np.zeros((0, 4, 4)))
        self.T_B_S_truth = None if T_B_S_truth is None else np.asarray(T_B_S_truth, dtype=float)
        self.camera = camera

        self._pending: list[_Record] = []
        # Face-state changes, each to take effect at the keyframe of pending record `position`.
        self._events: list[tuple[int, str, FaceState]] = []
        self._stamp_kind: str | None = None
        self._last: dict[str, np.ndarray] = {}  # last point of each trail already sent
        self._time: tuple[int, float] | None = None  # keyframe and stamp of the last record sent
        self.logged_keyframes = 0
        self._face_rows: dict[str, list[tuple[tuple[int, float], FaceState]]] = {}  # colour changes to send
        self._next_flush = time.perf_counter() + self.cfg.flush_seconds
        self._state = {f.id: FaceState.UNOBSERVED for f in plane_map.faces}
        self._colours = {s: self.cfg.colour(s.name.lower()) for s in FaceState}
        self._face_planes = plane_map.planes
        self._face_centres = plane_map.centres
        polygons = [np.asarray(f.polygon) for f in plane_map.faces]
        self._face_lo = np.array([p.min(axis=0) for p in polygons]).reshape(-1, 3) - self.cfg.observed_margin_m
        self._face_hi = np.array([p.max(axis=0) for p in polygons]).reshape(-1, 3) + self.cfg.observed_margin_m
        self._log_static()

    # -- static scene -----------------------------------------------------------------

    def _log_static(self):
        rr, cfg, log = self.rr, self.cfg, self.recording.log
        log(bp.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for face in self.plane_map.faces:
            vertices, triangles = face_mesh(face.polygon, face.holes, face.plane)
            if len(triangles):
                log(face_entity(face.id), rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles,
                                                    vertex_normals=np.broadcast_to(face.normal, vertices.shape)), static=True)
        if self.plane_map.faces:
            log(bp.LABELS, rr.Points3D(self._face_centres, labels=[f.id for f in self.plane_map.faces],
                                       radii=cfg.label_radius_m, colors=[cfg.colour_unobserved[:3]]), static=True)
        log(bp.SLAM, rr.TransformAxes3D(cfg.axes_length_m), static=True)
        log(bp.CAMERA, rr.TransformAxes3D(cfg.axes_length_m), static=True)
        if self.camera is not None:
            cam = self.camera
            log(bp.IMAGE, rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                     camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=cfg.frustum_m), static=True)
        trails = [(bp.RAW, cfg.colour_raw), (bp.CORRECTED, cfg.colour_corrected)]
        if len(self.T_B_C_truth[0]):
            trails.append((bp.TRUTH, cfg.colour_truth))
            for name, colour in (("corrected", cfg.colour_corrected), ("raw", cfg.colour_raw)):
                log(f"{bp.METRICS}/position_error_cm/{name}", rr.SeriesLines(colors=[colour], names=[name]), static=True)
        for unit in ("deg", "cm"):
            log(f"{bp.METRICS}/extrinsic_{unit}/sigma", rr.SeriesLines(names=[f"sigma {a}" for a in "xyz"]), static=True)
        for trail, colour in trails:
            log(trail, rr.LineStrips3D.from_fields(colors=[colour], radii=[cfg.trajectory_radius_m]), static=True)

    # -- events -----------------------------------------------------------------------

    def keyframe(self, index: int, stamp: float, *, T_S_C: np.ndarray, T_B_C: np.ndarray, T_B_S: np.ndarray,
                 cov_T_B_S: np.ndarray | None = None, planes: Sequence[PlaneObservation] = (),
                 plane_faces: Sequence[str | None] | None = None, associations: int | None = None,
                 latency_s: float | None = None, depth: np.ndarray | None = None):
        """One keyframe: the front-end's pose `T_S_C`, the estimates `T_B_C` and `T_B_S`
        (`cov_T_B_S` 6x6 in gtsam's Pose3 tangent order), the planes detected in C with the
        BIM face each one is associated with (None if none), the total number of matched
        landmarks, the time the backend spent, and the depth image as read from its PNG."""
        if self._stamp_kind is None:
            self._stamp_kind = "timestamp" if stamp > _UNIX_STAMP_MIN else "duration"
        self.logged_keyframes += 1
        self._pending.append(_Record(
            int(index), float(stamp), np.asarray(T_S_C, dtype=float), np.asarray(T_B_C, dtype=float),
            np.asarray(T_B_S, dtype=float), cov_T_B_S, planes,
            [None] * len(planes) if plane_faces is None else list(plane_faces), associations, latency_s,
            depth if self.cfg.depth_images and self.camera is not None else None))
        if time.perf_counter() >= self._next_flush:
            self.flush()

    def set_face_state(self, face_id: str, state: FaceState):
        """Set a face's state from the next keyframe on (or the last one, at the end)."""
        if face_id in self._state:
            self._events.append((len(self._pending), face_id, state))

    def trajectory(self, T_B_C: Sequence[np.ndarray]):
        """The whole final trajectory (e.g. offline smoothed), once, at the last keyframe."""
        self.flush()
        points = np.array([np.asarray(T)[:3, 3] for T in T_B_C]).reshape(-1, 3)
        self._log_now(bp.FINAL, self.rr.LineStrips3D([points], colors=[self.cfg.colour_final],
                                                     radii=self.cfg.trajectory_radius_m))

    def widths(self, widths) -> None:
        """The deviation report's room widths (`WidthRecord`s), once, at the last keyframe: a
        line from each width's first face across the room to the other's plane; where off plan
        in the deviating colour and labelled with the width as built and its change from plan."""
        self._distances(bp.WIDTHS, widths, 1.0, lambda w: f"{w.built_m:.3f} m")

    def thicknesses(self, thicknesses) -> None:
        """The deviation report's wall thicknesses (`ThicknessRecord`s), as `widths` draws
        widths: a line from the first face through the wall to the other side's plane."""
        self._distances(bp.THICKNESSES, thicknesses, -1.0, lambda t: f"{100 * t.built_m:.1f} cm")

    def _distances(self, entity: str, records, direction: float, built: Callable[[object], str]) -> None:
        index = self.plane_map.index
        records = [r for r in records if r.faces[0] in index]  # (`bimgraph view --bim` another model)
        if not records:
            return
        self.flush()
        strips, labels, colours = [], [], []
        for r in records:
            face = self.plane_map.faces[index[r.faces[0]]]
            start = np.asarray(face.centre, dtype=float)
            strips.append([start, start + direction * r.planned_m * np.asarray(face.normal)])
            off = r.status == "deviating"  # (labelled only then: widths across one room cross at its middle)
            labels.append(f"{built(r)} ({100 * (r.built_m - r.planned_m):+.1f} cm)" if off else "")
            colours.append((self.cfg.colour_deviating if off else self.cfg.colour_associated)[:3])
        self._log_now(entity, self.rr.LineStrips3D(strips, labels=labels, colors=colours,
                                                   radii=0.5 * self.cfg.trajectory_radius_m))

    def close(self):
        """Send everything and close the recording's sinks (an .rrd is complete only then)."""
        self.flush()
        if self._time is not None:
            self._apply_events(0, self._time)
            self._send_face_rows()
        self.recording.flush()
        self.recording.disconnect()

    # -- sending ----------------------------------------------------------------------

    def _log_now(self, entity: str, archetype):
        index, stamp = self._time or (0, 0.0)
        self.recording.set_time(bp.KEYFRAME, sequence=index)
        self.recording.set_time(bp.STAMP, **{self._stamp_kind or "duration": stamp})
        self.recording.log(entity, archetype)

    def _send(self, entity: str, archetype, index, stamp, lengths=None, **fields):
        rr = self.rr
        if len(index) == 0 or self._stamp_kind is None:
            return
        indexes = [rr.TimeColumn(bp.KEYFRAME, sequence=np.asarray(index)),
                   rr.TimeColumn(bp.STAMP, **{self._stamp_kind: np.asarray(stamp, dtype=float)})]
        columns = archetype.columns(**{k: np.asarray(v) for k, v in fields.items()})
        if lengths is not None:
            columns = columns.partition(lengths)
        self.recording.send_columns(entity, indexes=indexes, columns=columns)

    def _scalars(self, name: str, index, stamp, values, mask=None):
        """One series (values of shape (n,)) or several in one entity (shape (n, m))."""
        values = np.asarray(values, dtype=float)
        if mask is not None:
            index, stamp, values = np.asarray(index)[mask], np.asarray(stamp)[mask], values[mask]
        lengths = None if values.ndim == 1 else np.full(len(values), values.shape[1])
        self._send(f"{bp.METRICS}/{name}", self.rr.Scalars, index, stamp, lengths=lengths, scalars=values.reshape(-1))

    def _send_trail(self, trail: str, index, stamp, points: np.ndarray):
        """One segment per keyframe, from the previous keyframe's point to this one's; the
        3-D view accumulates them (see blueprint.TRAILS)."""
        if len(points) == 0:
            return
        previous = self._last.get(trail)
        self._last[trail] = points[-1]
        if previous is None:
            index, stamp = index[1:], stamp[1:]
        else:
            points = np.vstack([previous, points])
        self._send(trail, self.rr.LineStrips3D, index, stamp, lengths=np.ones(len(index), dtype=int),
                   strips=segments(points))

    def flush(self):
        """Send the buffered keyframes."""
        records, self._pending = self._pending, []
        if records:
            start = time.perf_counter()
            self._send_records(records)
            spent = time.perf_counter() - start
            self._next_flush = start + spent + max(self.cfg.flush_seconds, spent / self.cfg.flush_budget)

    def _send_records(self, records: list[_Record]):
        rr = self.rr
        index = np.array([r.index for r in records])
        stamp = np.array([r.stamp for r in records])
        if self._time is None:  # every face shows in its initial colour from the first keyframe on
            self._face_rows = {f: [((index[0], stamp[0]), FaceState.UNOBSERVED)] for f in self._state}
        T_B_C = np.stack([r.T_B_C for r in records])
        T_B_S = np.stack([r.T_B_S for r in records])
        T_B_C_raw = self.T_B_S_initial @ np.stack([r.T_S_C for r in records])

        self._send_trail(bp.RAW, index, stamp, T_B_C_raw[:, :3, 3])
        self._send_trail(bp.CORRECTED, index, stamp, T_B_C[:, :3, 3])
        self._send(bp.CAMERA, rr.Transform3D, index, stamp, translation=T_B_C[:, :3, 3], mat3x3=T_B_C[:, :3, :3])
        self._send(bp.SLAM, rr.Transform3D, index, stamp, translation=T_B_S[:, :3, 3], mat3x3=T_B_S[:, :3, :3])
        self._send_metrics(records, index, stamp, T_B_C, T_B_C_raw, T_B_S)
        self._send_planes(records, index, stamp)
        for i, r in enumerate(records):
            if r.depth is not None:
                self._time = (r.index, r.stamp)
                self._log_now(bp.IMAGE, rr.DepthImage(r.depth, meter=self.camera.depth_scale))
        self._time = (int(index[-1]), float(stamp[-1]))

    def _send_metrics(self, records, index, stamp, T_B_C, T_B_C_raw, T_B_S):
        latency = np.array([np.nan if r.latency_s is None else 1e3 * r.latency_s for r in records])
        self._scalars("latency_ms/backend", index, stamp, latency, ~np.isnan(latency))
        total = np.array([np.nan if r.associations is None else r.associations for r in records], dtype=float)
        self._scalars("associations/matched_landmarks", index, stamp, total, ~np.isnan(total))
        in_view = [sum(f is not None for f in r.plane_faces) for r in records]
        self._scalars("associations/planes_in_keyframe", index, stamp, in_view)
        self._scalars("extrinsic_deg/change", index, stamp, angles_deg(self.T_B_S_initial[:3, :3], T_B_S[:, :3, :3]))
        self._scalars("extrinsic_cm/change", index, stamp,
                      100.0 * np.linalg.norm(T_B_S[:, :3, 3] - self.T_B_S_initial[:3, 3], axis=1))
        with_cov = [i for i, r in enumerate(records) if r.cov_T_B_S is not None]
        if with_cov:
            # one-sigma per axis of B, as `bimgraph run` prints it (the covariance's own axes,
            # gtsam's right perturbation, are S's): an unobservable direction shows as a sigma
            # that stays at its prior
            sigma_rot, sigma_trans = sigmas_in_B(T_B_S[with_cov], [records[i].cov_T_B_S for i in with_cov])
            self._scalars("extrinsic_deg/sigma", index[with_cov], stamp[with_cov], np.degrees(sigma_rot))
            self._scalars("extrinsic_cm/sigma", index[with_cov], stamp[with_cov], 100.0 * sigma_trans)

        # The definitions of bimgraph.evaluation.metrics (translation error; extrinsic error
        # at the origin of S), vectorised: its per-pose scipy rotation costs ~200 us each.
        truth_stamps, truth_poses = self.T_B_C_truth
        rows = nearest_stamps(stamp, truth_stamps, T_MAX_DIFF_S)
        known = rows >= 0
        if known.any():
            truth = truth_poses[rows[known]]
            self._send_trail(bp.TRUTH, index[known], stamp[known], truth[:, :3, 3])
            for name, estimate in (("corrected", T_B_C), ("raw", T_B_C_raw)):
                self._scalars(f"position_error_cm/{name}", index[known], stamp[known],
                              100.0 * np.linalg.norm(estimate[known, :3, 3] - truth[:, :3, 3], axis=1))
        if self.T_B_S_truth is not None:
            self._scalars("extrinsic_deg/error", index, stamp, angles_deg(self.T_B_S_truth[:3, :3], T_B_S[:, :3, :3]))
            self._scalars("extrinsic_cm/error", index, stamp,
                          100.0 * np.linalg.norm(T_B_S[:, :3, 3] - self.T_B_S_truth[:3, 3], axis=1))

    def _send_planes(self, records, index, stamp):
        """Outlines of the detected planes (in C, drawn under the camera), the association
        lines from each associated plane's centre to its face's centre, and face states."""
        cfg, face_index = self.cfg, self.plane_map.index
        outlines, outline_colours, outline_rows = [], [], []
        lines, line_rows = [], []
        unmatched_C, unmatched_rows = [], []
        for r in records:
            n_outline = n_lines = 0
            for plane, face_id in zip(r.planes, r.plane_faces):
                if plane.polygon is not None:
                    outlines.append(plane.polygon + plane.polygon[:1])
                    outline_colours.append(cfg.colour_plane if face_id is None else cfg.colour_plane_associated)
                    n_outline += 1
                if face_id in face_index:
                    centre_B = r.T_B_C[:3, :3] @ plane_centre_C(plane) + r.T_B_C[:3, 3]
                    lines.append([centre_B, self._face_centres[face_index[face_id]]])
                    n_lines += 1
                elif face_id is None:
                    unmatched_C.append(plane)
                    unmatched_rows.append(len(outline_rows))
            outline_rows.append(n_outline)
            line_rows.append(n_lines)
        rings_C = closed_rings(outlines)
        colours = np.array(outline_colours, dtype=np.uint8).reshape(-1, 4)
        self._send(bp.PLANES, self.rr.LineStrips3D, index, stamp, lengths=outline_rows, strips=rings_C, colors=colours)
        if self.camera is not None:  # the same outlines in the camera's image
            self._send(bp.PLANES_2D, self.rr.LineStrips2D, index, stamp, lengths=outline_rows,
                       strips=project(rings_C, self.camera), colors=colours)
        self._send(bp.ASSOCIATIONS, self.rr.LineStrips3D, index, stamp, lengths=line_rows,
                   strips=np.array(lines, dtype=float).reshape(-1, 2, 3),
                   colors=np.tile(np.array(cfg.colour_association, dtype=np.uint8), (len(lines), 1)))

        seen = self._faces_seen(unmatched_C, np.array(unmatched_rows, dtype=int), records)
        for i, r in enumerate(records):
            self._apply_events(i, (r.index, r.stamp))
            for face_id in r.plane_faces:
                if face_id in face_index:
                    self._raise(face_id, FaceState.ASSOCIATED, (r.index, r.stamp))
            for face_row in seen.get(i, ()):
                self._raise(self.plane_map.faces[face_row].id, FaceState.OBSERVED, (r.index, r.stamp))
        self._events = [(pos - len(records), face, state) for pos, face, state in self._events if pos >= len(records)]
        self._send_face_rows()

    def _faces_seen(self, planes: list[PlaneObservation], rows: np.ndarray, records) -> dict[int, np.ndarray]:
        """For display only: which faces each unassociated plane lies on (nearly parallel,
        its centre close to the face's plane and within the face's box), by record."""
        if not planes or len(self._face_planes) == 0:
            return {}
        cfg = self.cfg
        T_B_C = np.stack([records[i].T_B_C for i in rows])
        n_C = np.array([p.plane[:3] for p in planes])
        n_B = np.einsum("kij,kj->ki", T_B_C[:, :3, :3], n_C)
        centres_B = np.einsum("kij,kj->ki", T_B_C[:, :3, :3], np.array([plane_centre_C(p) for p in planes])) + T_B_C[:, :3, 3]
        parallel = n_B @ self._face_planes[:, :3].T >= np.cos(np.radians(cfg.observed_angle_deg))
        near = np.abs(centres_B @ self._face_planes[:, :3].T + self._face_planes[:, 3]) <= cfg.observed_distance_m
        inside = np.all((centres_B[:, None, :] >= self._face_lo) & (centres_B[:, None, :] <= self._face_hi), axis=2)
        seen = defaultdict(list)
        for plane_row, face_row in zip(*np.nonzero(parallel & near & inside)):
            seen[int(rows[plane_row])].append(int(face_row))
        return seen

    def _apply_events(self, position: int, when: tuple[int, float]):
        for pos, face_id, state in self._events:
            if pos == position:
                self._change(face_id, state, when)

    def _raise(self, face_id: str, state: FaceState, when: tuple[int, float]):
        if state > self._state[face_id]:
            self._change(face_id, state, when)

    def _change(self, face_id: str, state: FaceState, when: tuple[int, float]):
        if self._state[face_id] != state:
            self._state[face_id] = state
            self._face_rows.setdefault(face_id, []).append((when, state))

    def _send_face_rows(self):
        for face_id, changes in self._face_rows.items():
            self._send(face_entity(face_id), self.rr.Mesh3D, [w[0] for w, _ in changes], [w[1] for w, _ in changes],
                       albedo_factor=np.array([self._colours[s] for _, s in changes], dtype=np.uint8))
        self._face_rows = {}
