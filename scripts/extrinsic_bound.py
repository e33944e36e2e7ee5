#!/usr/bin/env python
"""How well could any estimator place T_B_S, or measure a face's offset, on a simulated walk?
A Cramer-Rao bound.

The extrinsic is the frame S of the front-end's first camera in B, so it is placed by the
planes seen around the first keyframes and by the odometry linking them to the rest of the
walk. This script builds, at the truth, the Fisher information of the simulator's own model
of a walk (`bimgraph/sim`), made easier for the estimator in every respect it can be:
- the front-end (`bimgraph/sim/frontend.py`): each reported pose is the drifting pose times
  white noise (`noise_m`, `noise_deg`); the drifting pose is the true one moved by a random
  walk (`random_walk_m`, and `random_walk_deg` about up, per square-root metre) and by
  constant drift rates per metre walked (heading, and position along a horizontal direction),
  which are unknown (three parameters, `--known-drift` gives them);
- the planes: every detection is drawn with exactly the covariance it reports. The faces built
  as planned, the floor and the ceiling are known exactly, and known to be as planned (which
  bimgraph must find out); the faces built off plan and the clutter are planes of unknown
  position (their observations still tie the poses together).
The variables: the true poses T_B_C (X(k)), the drifted extrinsic of each keyframe
T_B_S_k = T_B_C * T_S_C^-1 (E(k)), which the random walk moves from T_B_S = E(0), and the
planes (L(j)). The marginal covariance of E(0) is a lower bound on the error covariance of
any unbiased estimate of T_B_S from the sequence. Printed per sequence: the bound's sigma per
horizontal axis, the RMS horizontal error sqrt(sx^2 + sy^2), P(horizontal error <= LIMIT)
for an estimator that reached the bound (a Gaussian error), and the sigma of the yaw.

With `--faces`, the same for the deviation report (issue 8): the bound on the offset at its
centre of every built face seen in enough keyframes, the estimator given every other face
built as planned (within `--tolerance`), every built face's direction, and not the offsets of
the faces built off plan; then the share of those faces an estimator at the bound would measure
within each limit.

With `--twin`, the faces built off plan are given too, where they were built: the bound of the
same walk against the plan as built. Its ratio to the plain bound is how much the deviations
alone must cost any estimator (issue 8's extrinsic ratios, scripts/eval_deviations.py's twin).

    python scripts/extrinsic_bound.py SEQ [SEQ ...] [--limit-cm 1 2] [--tolerance DEG MM] [--known-drift] [--twin | --faces [--report REL]]
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import E, L, X
from rich.console import Console
from rich.table import Table

from bimgraph.backend.pipeline import load_model, model_path
from bimgraph.config import Config, FrontEndConfig
from bimgraph.deviations.report import load_deviations
from bimgraph.errors import BimgraphError
from bimgraph.geometry import inverse, plane_from_frame
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import as_planned, load_groundtruth
from factors import face_tolerance_cov, plane_prior_factor

UP = np.array([0.0, 0.0, 1.0])
KNOWN = 1e-5  # sigma of what the estimator is given exactly (radians, metres)
UNKNOWN_M = 1.0  # sigma of an offset the estimator is not given (metres: no information beside a walk's)
DRIFT = gtsam.symbol("d", 0)  # the front-end's drift rates, unless given


def known_planes(truth, tolerance: tuple[float, float], measured: frozenset[str] = frozenset(),
                 twin: bool = False) -> dict[str, gtsam.noiseModel.Base]:
    """The noise of what the estimator is given of each face built as planned (its tilt and
    its offset at its centre within `tolerance`, radians and metres, or exactly where zero),
    and of the floor and ceiling (exactly), by element. Of the faces in `measured` it is given
    their direction, exactly (bimgraph must estimate it), and not their offset. With `twin`,
    every built face counts as built as planned: the plan moved to where the walls were built
    (scripts/eval_deviations.py's twin run)."""
    exact = gtsam.noiseModel.Isotropic.Sigma(3, KNOWN)
    known = {"floor": exact, "ceiling": exact}
    centres = {e["name"]: np.mean(e["polygon"], axis=0) for e in truth.as_built["elements"]}
    for face in truth.as_built["faces"]:
        face_id = face["face_id"]
        if face_id not in measured and not (as_planned(face) or (twin and face["built"])):
            continue
        basis = gtsam.Unit3(np.asarray(face["plane_as_built"][:3], dtype=float)).basis()
        if face_id in measured:
            known[face_id] = gaussian(face_tolerance_cov(basis, centres[face_id], KNOWN, UNKNOWN_M) + np.eye(3) * KNOWN**2)
        elif any(tolerance):
            known[face_id] = gaussian(face_tolerance_cov(basis, centres[face_id], *tolerance) + np.eye(3) * KNOWN**2)
        else:
            known[face_id] = exact
    return known


def gaussian(cov: np.ndarray) -> gtsam.noiseModel.Gaussian:
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def fisher_graph(sequence, truth, frontend, known: dict[str, gtsam.noiseModel.Base], known_drift: bool):
    """The factors of the easier problem, at the truth (their residuals zero), its values, the
    plane key of each element observed, and the index of each element's prior factor."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    white = np.diag(np.r_[np.full(3, np.radians(frontend.noise_deg)), np.full(3, frontend.noise_m)] ** 2 + KNOWN**2)
    rw_rot, rw_m = np.radians(frontend.random_walk_deg), frontend.random_walk_m
    planes, priors = {}, {}
    if not known_drift:
        values.insert(DRIFT, np.zeros(3))
    for k, kf in enumerate(sequence.keyframes):
        T_B_C, T_S_C = truth.T_B_C[k], kf.pose
        T_B_Sk = T_B_C @ inverse(T_S_C)
        values.insert(X(k), gtsam.Pose3(T_B_C))
        values.insert(E(k), gtsam.Pose3(T_B_Sk))
        # The reported pose: the drifted one times white noise (none on the first, which is S).
        graph.add(gtsam.BetweenFactorPose3(E(k), X(k), gtsam.Pose3(T_S_C), gaussian(white if k else np.eye(6) * KNOWN**2)))
        if k == 0:  # S is level, as B is
            graph.add(gtsam.AttitudeFactorPose3(E(0), gtsam.Unit3(UP), gtsam.noiseModel.Isotropic.Sigma(2, KNOWN), gtsam.Unit3(UP)))
        else:
            # A step's walk, in the drifting camera's frame (yaw about up, position isotropic),
            # moves the drifted extrinsic by its adjoint.
            length = float(np.linalg.norm(T_B_C[:3, 3] - truth.T_B_C[k - 1][:3, 3]))
            up_C = T_S_C[:3, :3].T @ UP
            walk = np.zeros((6, 6))
            walk[:3, :3] = rw_rot**2 * length * np.outer(up_C, up_C)
            walk[3:, 3:] = rw_m**2 * length * np.eye(3)
            Ad = gtsam.Pose3(T_S_C).AdjointMap()
            step = values.atPose3(E(k - 1)).between(gtsam.Pose3(T_B_Sk))
            noise = gaussian(Ad @ walk @ Ad.T + np.eye(6) * KNOWN**2)
            if known_drift:
                graph.add(gtsam.BetweenFactorPose3(E(k - 1), E(k), step, noise))
            else:
                # The drift rates (heading per metre about up; position per metre, horizontal in
                # S) move the drifted extrinsic as the walk does: the between factor's Jacobians
                # at its measurement, and the rates' through the same adjoint.
                per_rate = np.zeros((6, 3))
                per_rate[:3, 0] = length * up_C
                per_rate[3:, 1:] = length * T_S_C[:3, :3].T[:, :2]
                R = noise.R()  # whitened here: a JacobianFactor takes only a diagonal noise model
                linear = gtsam.JacobianFactor(E(k - 1), -R @ step.inverse().AdjointMap(), E(k), R,
                                              DRIFT, -R @ Ad @ per_rate, np.zeros(6), gtsam.noiseModel.Unit.Create(6))
                point = gtsam.Values()
                point.insert(E(k - 1), values.atPose3(E(k - 1)))
                point.insert(E(k), gtsam.Pose3(T_B_Sk))
                point.insert(DRIFT, np.zeros(3))
                graph.add(gtsam.LinearContainerFactor(linear, point))
        for observation, plane_truth in zip(kf.planes, truth.observations[k], strict=True):
            plane_C = np.asarray(plane_truth["plane_C"], dtype=float)
            element = plane_truth["element"]
            if element not in planes:
                planes[element] = L(len(planes))
                plane_B = plane_from_frame(plane_C, T_B_C)
                values.insert(planes[element], gtsam.OrientedPlane3(plane_B / np.linalg.norm(plane_B[:3])))
                if element in known:
                    priors[element] = graph.size()
                    graph.add(plane_prior_factor(plane_B, known[element], planes[element]))
            graph.add(gtsam.OrientedPlane3Factor(plane_C / np.linalg.norm(plane_C[:3]), gaussian(np.asarray(observation.cov)),
                                                 X(k), planes[element]))
    return graph, values, planes, priors


def load(root: Path):
    sequence, truth = load_sequence(root), load_groundtruth(root)
    if not (sequence.meta.simulated or {}).get("options", {}).get("frontend"):
        raise BimgraphError(f"{root}: not a simulated sequence (sequence.json has no simulated.options.frontend)")
    return sequence, truth, FrontEndConfig(**sequence.meta.simulated["options"]["frontend"])


def bound(root: Path, tolerance: tuple[float, float], known_drift: bool, twin: bool = False) -> dict:
    """The bound's covariance of T_B_S's horizontal position (m, in B) and its yaw sigma (deg)."""
    sequence, truth, frontend = load(root)
    graph, values, _, _ = fisher_graph(sequence, truth, frontend, known_planes(truth, tolerance, twin=twin), known_drift)
    cov = gtsam.Marginals(graph, values).marginalCovariance(E(0))
    R = truth.T_B_S[:3, :3]  # Pose3's tangent is in the body frame: rotate into B
    cov_t = R @ cov[3:, 3:] @ R.T
    cov_r = R @ cov[:3, :3] @ R.T
    return {"cov_xy": cov_t[:2, :2], "yaw_deg": float(np.degrees(np.sqrt(cov_r[2, 2])))}


def offset_sigma(cov: np.ndarray, plane: gtsam.OrientedPlane3, centre: np.ndarray) -> float:
    """The sigma of the plane's offset at `centre` (`-(n . c + d)`, as the deviation report
    measures it) from the plane's covariance in its tangent space (by central differences)."""
    def offset(delta):
        coefficients = plane.retract(delta).planeCoefficients()
        return -(coefficients[:3] @ centre + coefficients[3])
    h = 1e-6
    J = np.array([(offset(h * e) - offset(-h * e)) / (2 * h) for e in np.eye(3)])
    return float(np.sqrt(J @ cov @ J))


def face_bounds(root: Path, tolerance: tuple[float, float], known_drift: bool, min_keyframes: int) -> list[dict]:
    """The bound's sigma of the offset of every built face seen in at least `min_keyframes`
    keyframes, at the centre the deviation report measures it at (the plane map's), and its true
    offset there. The estimator is given every other face built as planned (within `tolerance`,
    as in `known_planes`), and every built face's direction: an easier problem than the
    deviation report's, so a lower bound."""
    sequence, truth, frontend = load(root)
    plane_map = load_model(model_path(root, sequence.meta, None), Config())
    seen = Counter(e for planes in truth.observations for e in {p["element"] for p in planes})
    faces = [f for f in truth.as_built["faces"] if f["built"] and seen[f["face_id"]] >= min_keyframes]
    moved = frozenset(f["face_id"] for f in faces if not as_planned(f))
    graph, values, planes, priors = fisher_graph(sequence, truth, frontend, known_planes(truth, tolerance, moved), known_drift)
    direction_only = known_planes(truth, tolerance, frozenset(f["face_id"] for f in faces))
    rows = []
    base = gtsam.Marginals(graph, values)
    for face in faces:
        face_id, key = face["face_id"], planes[face["face_id"]]
        if face_id in moved:
            cov = base.marginalCovariance(key)
        else:  # its offset is what is measured: its prior gives only its direction
            measured = gtsam.NonlinearFactorGraph()
            for i in range(graph.size()):  # shares the factors; clone() fails on LinearContainerFactor
                measured.add(graph.at(i))
            plane_B = values.atOrientedPlane3(key).planeCoefficients()
            measured.replace(priors[face_id], plane_prior_factor(plane_B, direction_only[face_id], key))
            cov = gtsam.Marginals(measured, values).marginalCovariance(key)
        centre = np.asarray(plane_map.faces[plane_map.index[face_id]].centre)
        as_built = np.asarray(face["plane_as_built"], dtype=float)
        rows.append({"face": face_id, "moved": face_id in moved, "keyframes": seen[face_id],
                     "sigma_m": offset_sigma(cov, values.atOrientedPlane3(key), centre),
                     "offset_m": float(-(as_built[:3] @ centre + as_built[3]))})
    return rows


def p_within(cov_xy: np.ndarray, limit: float, samples: int = 200_000) -> float:
    """P(|e| <= limit) for e ~ N(0, cov_xy), by sampling (seeded)."""
    e = np.random.default_rng(0).multivariate_normal(np.zeros(2), cov_xy, samples)
    return float((np.linalg.norm(e, axis=1) <= limit).mean())


def print_faces(sequences: list[Path], limits_cm: list[float], tolerance: tuple[float, float], known_drift: bool,
                min_keyframes: int, report: Path | None):
    """The face bounds' table; with `report` (a deviation report's path inside each sequence),
    only the faces it measured with enough evidence, its sigma and error beside the bound."""
    table = Table(title="Lower bound on the error of each built face's offset at its centre")
    measured_columns = ("bimgraph sigma mm", "bimgraph error mm") if report else ()
    for column in ("sequence", "face", "off plan", "keyframes", "sigma mm", *measured_columns, *(f"P(<= {c:g} cm)" for c in limits_cm)):
        table.add_column(column, justify="left" if column in ("sequence", "face") else "right", no_wrap=column == "face")
    share, within = np.zeros(len(limits_cm)), np.zeros(len(limits_cm))
    count = 0
    for root in sequences:
        scored = {f.face_id: f for f in load_deviations(root / report).faces
                  if f.status in ("within_tolerance", "deviating")} if report else None
        for row in face_bounds(root, tolerance, known_drift, min_keyframes):
            if scored is not None and row["face"] not in scored:
                continue
            p = [math.erf(c / 100 / (row["sigma_m"] * math.sqrt(2))) for c in limits_cm]
            share += p
            count += 1
            measured = ()
            if scored is not None:
                face = scored[row["face"]]
                error = abs(face.offset_m - row["offset_m"])
                within += [error <= c / 100 for c in limits_cm]
                measured = (f"{face.offset_sigma_m * 1000:.1f}", f"{error * 1000:.1f}")
            table.add_row(root.name, row["face"], "yes" if row["moved"] else "", str(row["keyframes"]),
                          f"{row['sigma_m'] * 1000:.1f}", *measured, *(f"{q:.2f}" for q in p))
    Console(width=200).print(table)
    for i, c in enumerate(limits_cm):
        line = f"within {c:g} cm, of {count} faces: {share[i] / max(count, 1):.3f} expected at the bound"
        print(line + (f", {within[i] / max(count, 1):.3f} measured by the report" if report else ""))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("--limit-cm", type=float, nargs="+", default=[1.0, 2.0])
    parser.add_argument("--tolerance", type=float, nargs=2, default=[0.0, 0.0], metavar=("DEG", "MM"),
                        help="give the faces built as planned only to this tilt and offset (at their centre), "
                             "as bimgraph's plane-to-BIM factors trust every face (default: exactly)")
    parser.add_argument("--known-drift", action="store_true",
                        help="give the estimator the front-end's drift rates too (default: estimated, as bimgraph must)")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--twin", action="store_true",
                        help="give the faces built off plan too, where they were built: the bound of the run against "
                             "the plan as built (scripts/eval_deviations.py's twin)")
    what.add_argument("--faces", action="store_true",
                        help="bound each built face's offset instead (issue 8's deviations), every other face built "
                             "as planned given (exactly, or within --tolerance) and every face's direction given")
    parser.add_argument("--min-keyframes", type=int, default=3, help="with --faces: faces seen in fewer keyframes are left out "
                        "(the deviation report's `deviations.min_keyframes`)")
    parser.add_argument("--report", type=Path, default=None, metavar="REL",
                        help="with --faces: only the faces the deviation report at SEQ/REL measured with enough evidence, "
                             "with its sigma and error (e.g. deviations_eval/deviations.json, which "
                             "scripts/eval_deviations.py writes)")
    args = parser.parse_args()
    tolerance = (np.radians(args.tolerance[0]), args.tolerance[1] / 1000)
    try:
        if args.faces:
            print_faces(args.sequences, args.limit_cm, tolerance, args.known_drift, args.min_keyframes, args.report)
            return
        table = Table(title="Lower bound on the error of T_B_S (position in B, horizontal)")
        for column in ("sequence", "sigma x, y cm", "RMS error cm", *(f"P(<= {c:g} cm)" for c in args.limit_cm), "yaw sigma deg"):
            table.add_column(column, justify="left" if column == "sequence" else "right")
        for root in args.sequences:
            b = bound(root, tolerance, args.known_drift, args.twin)
            sx, sy = np.sqrt(np.diag(b["cov_xy"])) * 100
            table.add_row(root.name, f"{sx:.2f}, {sy:.2f}", f"{np.hypot(sx, sy):.2f}",
                          *(f"{p_within(b['cov_xy'], c / 100):.2f}" for c in args.limit_cm), f"{b['yaw_deg']:.3f}")
        Console().print(table)
    except BimgraphError as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
