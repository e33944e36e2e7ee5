"""The backend on a synthetic world with exact ground truth: box rooms whose wall sides are the
plane map, a camera circling each room, noisy plane observations, a drifting front-end."""

import gtsam
import numpy as np
import pytest

from bimgraph.backend import (Alignment, Backend, BimAssociator, FaceIndex, Listener, planes_in_B_independent,
                              run_offline, run_online)
from bimgraph.backend.depth_tilt import DepthTilt
from bimgraph.backend.landmarks import Landmark
from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.config import BackendConfig
from bimgraph.evaluation.metrics import association_scores, ate, extrinsic_error
from bimgraph.geometry import exp_se3, inverse, make_pose, plane_from_frame, pose_to_tum
from bimgraph.sequence.format import Camera, Keyframe, PlaneObservation


@pytest.fixture(scope="module")
def scene():
    return make_scene(160, rooms=(2, 2), seed=3)


@pytest.fixture(scope="module")
def cfg():
    return BackendConfig()


class Recorder(Listener):
    def __init__(self):
        self.keyframes, self.matched, self.removed = [], [], []

    def on_keyframe(self, result):
        self.keyframes.append(result.index)

    def on_association(self, landmark_id, face_id, score):
        self.matched.append((landmark_id, face_id, score))

    def on_association_removed(self, landmark_id, face_id, reason):
        self.removed.append((landmark_id, face_id, reason))


def frontend_ate(scene):
    return ate([scene.initial.T_B_S @ kf.pose for kf in scene.keyframes], scene.T_B_C)


def test_online(scene, cfg):
    listener = Recorder()
    results = run_online(scene.keyframes, scene.plane_map, cfg, scene.initial, listener=listener)
    precision, recall = association_scores(results.associations(), scene.truth)
    assert precision == 1.0 and recall >= 0.9
    rot_deg, trans_cm = extrinsic_error(results.T_B_S, scene.T_B_S)
    assert rot_deg < 0.5 and trans_cm < 3.0  # from 2 deg and 17 cm
    assert ate(results.T_B_C, scene.T_B_C) < frontend_ate(scene) / 3
    assert listener.keyframes == [kf.index for kf in scene.keyframes]
    assert {face for _, face, _ in listener.matched} == {f.id for f in scene.plane_map.faces}
    # the reported covariance is a covariance, and the error is plausible under it
    assert np.all(np.linalg.eigvalsh(results.cov_T_B_S) > 0)
    sigma_rot_deg = np.degrees(np.sqrt(np.diag(results.cov_T_B_S)[:3]).max())
    assert rot_deg < 4 * sigma_rot_deg
    # walls only: height can never be observed, and is reported
    assert results.unobservable == [{"kind": "translation", "axis_B": [0.0, 0.0, 1.0]}]


def test_offline_close_to_oracle(scene, cfg):
    ours = run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    oracle = run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial, oracle=scene.truth)
    precision, recall = association_scores(ours.associations(), scene.truth)
    assert precision == 1.0 and recall >= 0.95
    assert association_scores(oracle.associations(), scene.truth) == (1.0, 1.0)
    # a short scene: a wall seen twice on entering a room stays unmatched (min_observations),
    # which the oracle uses; on the simulator's sequences the gap is smaller
    assert ate(ours.T_B_C, scene.T_B_C) <= 1.2 * ate(oracle.T_B_C, scene.T_B_C)
    rot_deg, trans_cm = extrinsic_error(ours.T_B_S, scene.T_B_S)
    assert rot_deg < 0.5 and trans_cm < 3.0
    assert ours.rounds >= 1 and ours.timings["total_s"] > 0


def test_offline_merges_only_in_a_round_that_split_nothing(scene, cfg, monkeypatch):
    """A landmark spanning sections of a wall built apart is split before any merging:
    compared whole with the landmark of one section, it is one plane with neither, and that
    landmark would lose its face for good (deviation seed 2: a wall's section 6.8 cm off).
    Merging waits for the next round, whose marginals know the new landmarks."""
    from bimgraph.backend.reassociation import Reassociation

    calls = []
    real_split, real_merge = Reassociation.split, Reassociation.merge

    def split(self, values):
        real = real_split(self, values)
        calls.append("split")
        return real or calls.count("split") == 1  # the first round reports a split

    def merge(self, values, marginals):
        calls.append("merge")
        return real_merge(self, values, marginals)

    monkeypatch.setattr(Reassociation, "split", split)
    monkeypatch.setattr(Reassociation, "merge", merge)
    run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    assert calls[:3] == ["split", "split", "merge"]


def test_offline_judges_each_face_once_even_when_the_rounds_run_out(scene, monkeypatch):
    """The rounds end at `offline.max_rounds`; if the last one split a landmark, the face it
    left with two landmarks is still merged before the robust alignment judges, which would
    otherwise count that face twice (deviation seed 2: five landmarks on a wall built 7 cm
    off outvoted the sound walls, extrinsic 10.5 cm off). Here the first round's split is
    made to leave a matched landmark's later observations on a second landmark of its face."""
    from bimgraph.backend.graph import L
    from bimgraph.backend.reassociation import Reassociation
    from bimgraph.backend.robust_alignment import RobustAlignment

    cfg = BackendConfig()
    cfg.offline.max_rounds = 1
    real_split, real_decide = Reassociation.split, RobustAlignment.decide
    splits, judged = [], []

    def split(self, values):
        splits.append(values)
        if len(splits) > 1:
            return real_split(self, values)
        lm = max((x for x in self.landmarks.current() if x.face is not None), key=lambda x: len(x.observations))
        half = len(lm.observations) // 2
        twin = Landmark(len(self.landmarks), lm.anchor, lm.plane_A, lm.cov_A, lm.T_S_A, face=lm.face, score=lm.score)
        twin.observations, twin.centres_A = lm.observations[half:], lm.centres_A[half:]
        lm.observations, lm.centres_A = lm.observations[:half], lm.centres_A[:half]
        self.landmarks.add(twin)
        values.insert(L(twin.id), gtsam.OrientedPlane3(twin.plane_A))
        return True

    def decide(self, matches, reduced):
        judged.append([face for _, face in matches])
        return real_decide(self, matches, reduced)

    monkeypatch.setattr(Reassociation, "split", split)
    monkeypatch.setattr(RobustAlignment, "decide", decide)
    run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    assert len(splits) == 1  # the rounds ran out after it
    assert judged and all(len(faces) == len(set(faces)) for faces in judged)


def test_corridor_runs_and_reports_unobservable(cfg):
    """All faces +-y: x translation and rotation about y cannot be observed; the run goes to
    the end, keeps the initial alignment there, and says so."""
    scene = make_scene(60, rooms=(2, 1), seed=5, only_y_walls=True)
    results = run_online(scene.keyframes, scene.plane_map, cfg, scene.initial)
    kinds = {(u["kind"], tuple(np.round(u["axis_B"], 6))) for u in results.unobservable}
    assert ("translation", (1.0, 0.0, 0.0)) in kinds and ("rotation", (0.0, 1.0, 0.0)) in kinds
    # x of the S origin in B stays at the initial alignment's (locked); across the corridor (y)
    # the cameras are corrected
    assert results.T_B_S[0, 3] == pytest.approx(scene.initial.T_B_S[0, 3], abs=2e-3)

    def y_rms(T_B_C):
        return np.sqrt(np.mean([(a[1, 3] - b[1, 3]) ** 2 for a, b in zip(T_B_C, scene.T_B_C)]))

    assert y_rms(results.T_B_C) < y_rms([scene.initial.T_B_S @ kf.pose for kf in scene.keyframes]) / 3
    offline = run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    assert ("translation", (1.0, 0.0, 0.0)) in {(u["kind"], tuple(np.round(u["axis_B"], 6))) for u in offline.unobservable}


def test_plane_covariances_are_floored(cfg):
    """An overconfident front-end's planes (here 1e-8 m) are raised to the floor where the
    graph and the association take them; a missing covariance is the default."""
    from bimgraph.backend.graph import FactorBuilder

    build = FactorBuilder(cfg)
    floored = build.observation_cov(np.diag([1e-16, 1e-16, 1e-16]) + 1e-18)
    floor = [np.radians(cfg.noise.plane_min_normal_deg) ** 2] * 2 + [cfg.noise.plane_min_offset_m**2]
    assert np.diag(floored) == pytest.approx(floor, rel=1e-6)
    assert floored[0, 1] == pytest.approx(1e-18)
    loose = np.diag([1e-4, 1e-4, 1e-3])
    assert np.array_equal(build.observation_cov(loose), loose)
    assert np.array_equal(build.observation_cov(None), build.default_plane_cov)


def test_a_singular_graph_is_an_error_naming_the_variable():
    """gtsam's IndeterminantLinearSystemException, which `bimgraph run` turns into one line and
    exit code 5 (`bimgraph.errors.SingularError`)."""
    from bimgraph.backend.graph import X, singular_as_error
    from bimgraph.errors import SingularError

    graph = gtsam.NonlinearFactorGraph()  # two poses, one relative measurement, no prior
    graph.add(gtsam.BetweenFactorPose3(X(0), X(1), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), gtsam.Pose3())
    with pytest.raises(SingularError, match=r"singular at keyframe [01]:"), singular_as_error():
        gtsam.ISAM2().update(graph, values)
    with pytest.raises(RuntimeError, match="other"), singular_as_error():
        raise RuntimeError("other")
    # (the robust alignment's Cholesky of a marginal, on a walk 100 km from S's origin)
    with pytest.raises(SingularError, match="not positive definite"), singular_as_error():
        np.linalg.cholesky(-np.eye(2))


def test_bim_association_alone(scene, cfg):
    """The association baselines reuse: planes in S with covariances and a T_B_S estimate."""
    faces = FaceIndex(scene.plane_map, cfg.bim_association)
    bim = BimAssociator(faces, cfg.bim_association)
    T_B_S = scene.T_B_S @ exp_se3(np.array([0, 0, 0.005, 0.02, -0.01, 0]))
    cov_T_B_S = np.diag([1e-5] * 3 + [1e-3] * 3)
    T_S_B = inverse(scene.T_B_S)
    chosen = ["r00N", "r00E", "r11W"]
    planes_S, extents_S = [], []
    for face_id in chosen:
        face = scene.plane_map.faces[scene.plane_map.index[face_id]]
        planes_S.append(plane_from_frame(face.plane, T_S_B))
        corners = np.asarray(face.polygon)
        shrunk = corners.mean(axis=0) + 0.6 * (corners - corners.mean(axis=0))
        extents_S.append(shrunk @ T_S_B[:3, :3].T + T_S_B[:3, 3])
    # clutter: a cabinet front 0.4 m in front of r00N, and a board leaning 10 deg against r00E
    cabinet = scene.plane_map.faces[scene.plane_map.index["r00N"]].plane + np.r_[0, 0, 0, -0.4]
    tilt = make_pose(gtsam.Rot3.Ry(np.radians(10)).matrix(), np.zeros(3))
    board = plane_from_frame(scene.plane_map.faces[scene.plane_map.index["r00E"]].plane, tilt)
    for plane_B in (cabinet, board):
        planes_S.append(plane_from_frame(plane_B, T_S_B))
        extents_S.append(np.zeros((0, 3)))
    covs = np.array([np.diag([1e-5, 1e-5, 1e-4])] * len(planes_S))
    candidates = planes_in_B_independent(T_B_S, cov_T_B_S, np.array(planes_S), covs, extents_S, [4.0] * len(planes_S))
    matches = {m.landmark: m.face for m in bim.match(candidates)}
    assert matches == {0: "r00N", 1: "r00E", 2: "r11W"}


def _scene_with_a_board(seed: int, foot: float = 0.12, top: float = 0.05):
    """One room; from half-way on, a board leaning on wall r00E hides the wall: its foot `foot`
    out, its top at 2 m `top` off the wall (by default 2.0 deg and 8.5 cm off at its centre;
    equal: a cabinet's front)."""
    from bimgraph.backend.synthetic import _observe
    from bimgraph.bim.planemap import BimFace

    scene = make_scene(200, rooms=(1, 1), seed=seed)
    x = max(p[0] for f in scene.plane_map.faces for p in f.polygon)
    poly = np.array([(x - foot, 0.5, 0.0), (x - foot, 3.5, 0.0), (x - top, 3.5, 2.0), (x - top, 0.5, 2.0)])
    n = np.cross(poly[1] - poly[0], poly[3] - poly[0])
    n = -n / np.linalg.norm(n) if n[0] > 0 else n / np.linalg.norm(n)
    board = BimFace(id="board", wall_guid="board", normal=tuple(n), offset=float(-n @ poly[0]), polygon=[tuple(p) for p in poly])
    rng = np.random.default_rng(seed)
    hidden = []
    for k, kf in enumerate(scene.keyframes[len(scene.keyframes) // 2:], start=len(scene.keyframes) // 2):
        for i in range(len(kf.planes)):
            if scene.truth.get((k, i)) == "r00E":
                seen = _observe(board, scene.T_B_C[k], rng, np.radians(0.5), 0.01, 2.0)
                if seen is not None:
                    kf.planes[i] = seen
                    scene.truth[(k, i)] = None
                    hidden.append((k, i))
    return scene, hidden


@pytest.mark.parametrize("seed", [1, 2])
def test_offline_keeps_a_board_apart_from_the_wall_it_hides(cfg, seed):
    """The board is close enough to the wall's face to be matched to it, but it is not the
    wall's plane: the offline merge keeps it apart, and the wall keeps its match."""
    scene, hidden = _scene_with_a_board(seed)
    assert len(hidden) > 10
    results = run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    faces = results.associations()
    assert not any(faces.get(obs) == "r00E" for obs in hidden)
    assert sum(face == "r00E" for face in faces.values()) >= 10


@pytest.mark.parametrize("seed", [1, 3])
def test_online_keeps_a_cabinet_front_apart_from_the_wall_behind_it(cfg, seed):
    """A cabinet's front 15 cm before wall r00E, parallel, passes the gate's 5 cm offset
    tolerance once the wall's own landmark is matched; online, the face then has two landmarks
    that are not one plane, and the one farther from it goes without (as offline merging
    decides). The test is only as strong as the two landmarks' joint covariance when the front
    is matched: with scene seed 2 the young front still passes `offline.merge_gate` as one plane
    with the wall (7 of seeds 0-7 keep it apart)."""
    scene, hidden = _scene_with_a_board(seed, foot=0.15, top=0.15)
    faces = run_online(scene.keyframes, scene.plane_map, cfg, scene.initial).associations()
    assert not any(faces.get(obs) == "r00E" for obs in hidden)
    assert sum(face == "r00E" for face in faces.values()) >= 10


def test_a_landmark_takes_one_plane_to_bim_factor():
    """Queued or in iSAM2 already, a second plane-to-BIM factor for one landmark is refused."""
    from bimgraph.backend.incremental import IncrementalGraph

    graph = IncrementalGraph(BackendConfig(), np.eye(4), np.eye(6) * 0.01)
    plane, centre = np.array([1.0, 0.0, 0.0, -2.0]), np.array([2.0, 0.0, 1.0])
    graph.add_bim(0, 0, plane, centre)
    with pytest.raises(ValueError, match="already"):
        graph.add_bim(0, 0, plane, centre)


def test_a_landmarks_plane_to_bim_factor_is_replaced_and_left_out_of_the_batch_graph():
    """What the online judgement does to the graph: the factor it gives a landmark replaces
    the one in iSAM2 (none: taken out; taking out a factor that is not there is no error), and
    the batch graph it judges over holds every other factor."""
    from bimgraph.backend.incremental import IncrementalGraph

    graph = IncrementalGraph(BackendConfig(), np.eye(4), np.eye(6) * 0.01)
    plane_C, face, centre = np.array([1.0, 0.0, 0.0, -2.0]), np.array([1.0, 0.0, 0.0, -2.0]), np.array([2.0, 0.0, 1.0])
    graph.insert_pose(0, np.eye(4))
    graph.insert_plane(0, plane_C)
    graph.add(graph.build.first_pose(0, np.eye(4)))
    graph.add(graph.build.anchor_observation(0, plane_C, graph.build.default_plane_cov))
    graph.add_bim(0, 0, face, centre)
    graph.update()
    assert graph.without_bim().size() == 3  # the extrinsic's prior, the first pose's, the observation
    loose = graph.build.bim(0, 0, face, centre, tolerance=(np.radians(1.0), 100.0))
    graph.set_bim(0, loose)
    graph.update()
    live = graph.isam.getFactorsUnsafe()
    assert sum(live.exists(i) for i in range(live.size())) == 4
    assert live.at(graph.bim_index[0]).equals(loose, 1e-12)
    graph.set_bim(0, None)
    graph.update()
    assert 0 not in graph.bim_index and graph.without_bim().size() == 3
    graph.remove_bim(0)  # nothing there: no error


def offline_with_one_landmark(matched: str, seen_on: list[str]):
    """An offline estimator on three rooms in a row whose one landmark, matched to south face
    `matched`, has seen the centre of face `seen_on[k]` at keyframe k; and the values `Reassociation.split`
    reads."""
    from bimgraph.backend.graph import E, L, X
    from bimgraph.backend.offline import OfflineEstimator

    scene = make_scene(10, rooms=(3, 1), seed=1)
    est = OfflineEstimator(scene.plane_map, BackendConfig(), scene.initial)
    faces = {f.id: f for f in scene.plane_map.faces}
    T_S_B = inverse(scene.initial.T_B_S)
    values = gtsam.Values()
    values.insert(E, gtsam.Pose3(T_S_B))
    plane_S = plane_from_frame(np.array([*faces[matched].normal, faces[matched].offset]), scene.initial.T_B_S)
    lm = Landmark(0, 0, plane_S, np.eye(3) * 1e-4, np.eye(4), face=matched)
    for k, face in enumerate(seen_on):
        values.insert(X(k), gtsam.Pose3(np.eye(4)))
        lm.add_observation(k, 0, (T_S_B[:3, :3] @ np.asarray(faces[face].centre) + T_S_B[:3, 3])[None], None, 16)
    est.landmarks.add(lm)
    values.insert(L(0), gtsam.OrientedPlane3(plane_S))
    return est, values


def test_offline_splits_a_landmark_per_section_in_the_order_it_saw_them():
    """A landmark whose observations lie on several sections of a wall becomes one per section,
    numbered in the order of their first observations: by a set of face ids, runs differed
    with Python's string hashing."""
    est, values = offline_with_one_landmark("r10S", ["r20S", "r00S", "r20S", "r10S", "r20S"])
    assert est.reassociation.split(values)
    assert [(x.face, [k for k, _ in x.observations]) for x in est.landmarks.items] == [
        ("r20S", [0, 2, 4]), ("r00S", [1]), ("r10S", [3])]


def test_offline_moves_a_landmark_wholly_on_another_section_to_it():
    """A landmark matched to one section of a wall (as the association found it, early) whose
    observations all lie on another takes that one: the deviation report had blamed a
    basement wall for the coplanar wall above it."""
    est, values = offline_with_one_landmark("r10S", ["r20S"] * 3)
    assert est.reassociation.split(values)  # (a change: the next round solves with the face's own factor)
    assert [(x.face, len(x.observations)) for x in est.landmarks.items] == [("r20S", 3)]
    assert not est.reassociation.split(values)


@pytest.mark.parametrize("tilt", [None, DepthTilt(Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5), 0.002)])
def test_a_wall_seen_in_two_parts_becomes_one_landmark_online(tilt):
    """A wall seen at one end, then at the other (too far apart for the SLAM association's
    extent check), makes two landmarks of one face; once both are matched, the second merges
    into the first: one plane-to-BIM factor for the face, every observation on one landmark
    (with the depth tilt variable too, each through a moved anchor of the landmark kept)."""
    # the wall's face is y = 0 facing +y, 4 m by 3 m; the camera at y = 2 looks along -y
    plane_map = PlaneMap(faces=[BimFace(id="w", wall_guid="w", normal=(0, 1, 0), offset=0.0,
                                        polygon=[(0, 0, 0), (4, 0, 0), (4, 0, 3), (0, 0, 3)])])
    R_B_C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z_C = -y_B, y_C = -z_B
    keyframes = []
    for k, x in enumerate([0.6, 0.7, 0.8, 0.9, 1.0, 3.0, 3.1, 3.2, 3.3, 3.4]):
        T_B_C = make_pose(R_B_C, np.array([x, 2.0, 1.5]))
        corners_B = np.array([[x - 0.6, 0, 0.5], [x + 0.6, 0, 0.5], [x + 0.6, 0, 2.5], [x - 0.6, 0, 2.5]])
        polygon_C = (corners_B - T_B_C[:3, 3]) @ T_B_C[:3, :3]
        n_C = T_B_C[:3, :3].T @ np.array([0.0, 1.0, 0.0])
        plane = PlaneObservation(n=tuple(n_C), d=2.0, cov=np.diag([1e-6, 1e-6, 1e-5]).tolist(), polygon=polygon_C.tolist())
        keyframes.append(Keyframe(index=k, stamp=float(k), T_S_C=tuple(pose_to_tum(T_B_C)), planes=[plane]))
    initial = Alignment(np.eye(4), np.diag([1e-4] * 3 + [1e-4] * 3))
    backend = Backend(plane_map, BackendConfig(), initial, tilt=tilt)
    results = [backend.process(kf) for kf in keyframes]
    first, second = backend.landmarks[0], backend.landmarks[1]
    assert second.merged_into == first.id and first.face == "w" and second.face is None
    assert len(first.observations) == len(keyframes)
    factors = backend.graph.isam.getFactorsUnsafe()
    kept = [factors.at(i) for i in backend.graph.observation_index[first.id]]
    assert len(kept) == len(keyframes) and not backend.graph.observation_index.get(second.id)
    anchors = {gtsam.Symbol(f.keys()[1]).chr() for f in kept if len(f.keys()) == 3}
    assert anchors == ({ord("x")} if tilt is None else {ord("m")})
    assert list(backend.graph.bim_index) == [first.id] and backend.landmarks.current() == [first]
    assert {a.landmark for a in results[-1].associations} == {first.id}


def test_online_revises_a_match_no_longer_observed():
    """A landmark matched wrongly and never seen again loses its match on the next refresh of
    every landmark (`isam2.refresh_every`): online, a clutter plane matched at keyframe 15 of
    site 3, while the extrinsic was uncertain, kept its wrong face to the end."""
    from bimgraph.backend.online import Backend

    scene = make_scene(120, rooms=(2, 1), seed=0)
    cfg = BackendConfig()
    backend = Backend(scene.plane_map, cfg, scene.initial)
    last_seen = {}
    for kf in scene.keyframes:
        for a in backend.process(kf).associations:
            last_seen[a.landmark] = kf.index
    # a wall of the first room, last seen well before the end of the walk
    j = min((j for j, k in last_seen.items() if backend.landmarks[j].face is not None and k < 80),
            key=lambda j: last_seen[j])
    lm = backend.landmarks[j]
    normal_B = scene.initial.T_B_S[:3, :3] @ lm.plane_S[:3]
    wrong = next(f.id for f in scene.plane_map.faces if np.dot(f.normal, normal_B) < 0.5)

    backend = Backend(scene.plane_map, cfg, scene.initial)
    for kf in scene.keyframes:
        backend.process(kf)
        if kf.index == last_seen[j]:
            if backend.landmarks[j].face is not None:
                backend.matches.unmatch(backend.landmarks[j], "test")
            backend.matches.set_face(j, wrong, 0.0)
            matched_at = kf.index
    assert matched_at + cfg.isam2.refresh_every < scene.keyframes[-1].index
    assert backend.landmarks[j].face is None and wrong in backend.landmarks[j].rejected
