"""The simulation pipeline: building -> as-built world -> walk -> front-end -> observations,
written as a sequence folder with its ground truth (`bimgraph simulate`).

Generated scenarios are written as IFC4 into the folder and read back through the IFC importer,
exactly like a user's model. Every random draw comes from one seed, split into independent
streams per stage, so the same seed gives the same files byte for byte.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.config import Config
from bimgraph.errors import ConfigError, InputError
from bimgraph.files import existing_file, new_folder, uninterrupted
from bimgraph.geometry import make_pose
from bimgraph.sequence.format import (KEYFRAMES_FILE, META_FILE, Camera, InitialAlignment, Keyframe, Sequence, SequenceMeta,
                                      load_meta, save_sequence)
from bimgraph.sequence.groundtruth import FOLDER, LABELS_FOLDER, GroundTruth, pose7, rounded, write_groundtruth
from bimgraph.sim import clutter, occupancy, observe, world
from bimgraph.sim.frontend import simulate_frontend
from bimgraph.sim.scenarios import SCENARIOS
from bimgraph.sim.trajectory import plan_trajectory

MODEL_FILE = "model.ifc"
# what a simulation writes into its folder (one in the planes mode leaves the depth mode's out)
WRITTEN = (META_FILE, KEYFRAMES_FILE, MODEL_FILE, FOLDER, "depth", "rgb", "depth.txt", "rgb.txt")
SENSORS = ("planes", "depth")
# Furniture of each kind of building (the site gets pallets of material instead of desks).
KINDS = {"office": ("box", "desk", "cabinet"), "site": ("box", "pallet"), "ifc": ("box", "desk", "cabinet")}
# Identity of a generated model's GlobalIds, so that the same scenario gives the same file.
_GUID_NAMESPACE = "bimgraph.simulate"


@dataclass
class SimOptions:
    output: Path
    scenario: str | None = None
    ifc: Path | None = None
    sensor: str = "planes"
    keyframes: int = 600
    seed: int = 0

    def check(self) -> None:
        if self.scenario is not None and self.ifc is not None:
            raise ConfigError("give either --scenario or --ifc, not both")
        if self.scenario is not None and self.scenario not in SCENARIOS:
            raise ConfigError(f"--scenario must be one of {', '.join(SCENARIOS)}, not {self.scenario!r}")
        if self.sensor not in SENSORS:
            raise ConfigError(f"--sensor must be one of {', '.join(SENSORS)}, not {self.sensor!r}")
        if self.keyframes < 2:
            raise ConfigError(f"--keyframes must be at least 2, not {self.keyframes}")
        if self.seed < 0:
            raise ConfigError(f"--seed must be non-negative, not {self.seed}")
        if self.ifc is not None:
            existing_file(self.ifc)


def freeze_ifc(path: Path, name: str) -> None:
    """Make a written IFC reproducible: GlobalIds from the entity order (ifcopenshell draws them
    from the system's random source), sets in entity order, a fixed time stamp."""
    import ifcopenshell
    import ifcopenshell.guid

    import ifcopenshell.ifcopenshell_wrapper as wrapper

    model = ifcopenshell.open(str(path))
    schema = wrapper.schema_by_name(model.schema)
    for i, entity in enumerate(sorted(model.by_type("IfcRoot"), key=lambda e: e.id())):
        digest = hashlib.md5(f"{_GUID_NAMESPACE}/{name}/{i}".encode()).digest()
        entity.GlobalId = ifcopenshell.guid.compress(uuid.UUID(bytes=digest).hex)
    # SETs of entities are written in Python set order (memory addresses): sort them.
    for entity in model:
        for index, attribute in enumerate(schema.declaration_by_name(entity.is_a()).all_attributes()):
            aggregate = attribute.type_of_attribute().as_aggregation_type()
            value = entity[index]
            if aggregate and aggregate.type_of_aggregation_string() == "set" and value and \
                    all(isinstance(v, ifcopenshell.entity_instance) for v in value):
                entity[index] = sorted(value, key=lambda e: e.id())
    model.header.file_name.time_stamp = "2000-01-01T00:00:00"
    model.write(str(path))


def initial_alignment(T_B_S: np.ndarray, rot_range, trans_range, rng: np.random.Generator):
    """A user's manual alignment: the true T_B_S turned about gravity and shifted sideways."""
    yaw = np.radians(rng.uniform(*rot_range)) * rng.choice([-1.0, 1.0])
    heading = rng.uniform(0.0, 2 * np.pi)
    shift = rng.uniform(*trans_range) * np.array([np.cos(heading), np.sin(heading), 0.0])
    R = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
    return make_pose(R @ T_B_S[:3, :3], T_B_S[:3, 3] + shift), float(np.degrees(yaw)), shift


def _as_built_record(storey: world.Storey, deviations, elements) -> dict:
    return {
        "storey": {"name": storey.name, "floor_z": rounded(storey.floor_z), "ceiling_z": rounded(storey.ceiling_z)},
        "faces": [
            {"face_id": d.face_id, "wall_guid": d.wall_guid, "built": d.built, "offset_m": rounded(d.offset_m),
             "tilt_deg": rounded(d.tilt_deg), "pivot": rounded(d.pivot), "axis": rounded(d.axis),
             "plane_planned": rounded(d.plane_planned), "plane_as_built": rounded(d.plane_as_built)}
            for d in deviations
        ],
        "elements": [
            {"index": i, "name": e.name, "kind": e.kind, "face_id": e.face_id, "plane": rounded(e.plane),
             "polygon": [rounded(p, 6) for p in e.polygon], "holes": [[rounded(p, 6) for p in h] for h in e.holes]}
            for i, e in enumerate(elements)
        ],
    }


def simulate(opts: SimOptions, cfg: Config, log: Callable[[str], None] = lambda m: None,
             progress: Callable[[int, int], None] = lambda done, total: None,
             stage: Callable[[str], None] = lambda text: None) -> dict:
    """Write the sequence folder `opts.output`; returns a summary (counts, drift, timings).
    `progress(done, total)` hears each keyframe, `stage(what)` each step before them (on a
    building of a thousand walls they take a minute). The folder is new, empty, or holds an
    earlier simulation, which this one replaces whole (its files in `WRITTEN`; a depth walk's
    images outlived a planes walk written over it); anything else there is refused. The
    sequence is written beside the folder and moved in once complete: a simulation that fails
    (a truncated IFC, a storey without rooms, Ctrl-C) leaves the folder as it was, or none,
    since an empty or half-written sequence folder would stand as a sequence."""
    opts.check()
    out = Path(opts.output)
    _check_replaceable(out)
    with new_folder(out.parent), tempfile.TemporaryDirectory(prefix=f".{out.name}.", dir=out.parent) as tmp:
        summary = _simulate(dataclasses.replace(opts, output=Path(tmp)), cfg, log, progress, stage)
        with uninterrupted():
            out.mkdir(exist_ok=True)
            for name in WRITTEN:
                if (out / name).is_dir():
                    shutil.rmtree(out / name)
                else:
                    (out / name).unlink(missing_ok=True)
            for written in Path(tmp).iterdir():
                os.replace(written, out / written.name)
    return summary


def _check_replaceable(out: Path) -> None:
    """An InputError unless `out` is new, empty or a simulated sequence folder (a user's own
    recording, or a run's outputs, must not go)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: is a file, not a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return
    if not (out / META_FILE).is_file():
        raise InputError(f"{out}: holds files but no sequence; simulate writes a new or empty folder, "
                         "or over a sequence it simulated before")
    if load_meta(out).simulated is None:
        raise InputError(f"{out}: holds a sequence that was not simulated; simulate would replace it")
    from bimgraph.backend.pipeline import run_outputs_in  # (a second of gtsam, for a folder that holds a sequence)

    if outputs := run_outputs_in(out):
        raise InputError(f"{out}: holds a run's outputs ({', '.join(outputs)}), which a new walk would leave "
                         "stale; move them, or simulate into another folder")


def _simulate(opts: SimOptions, cfg: Config, log: Callable[[str], None], progress: Callable[[int, int], None],
              stage: Callable[[str], None]) -> dict:
    from bimgraph.bim.ifc_import import import_ifc
    from bimgraph.sim.render import DepthRenderer

    scenario = opts.scenario if opts.scenario is not None or opts.ifc is not None else "office"
    sim = cfg.sim
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        timings[name] = round(now - clock, 3)
        clock = now

    out = Path(opts.output)
    if scenario is not None:
        from bimgraph.bim.ifc_write import write_ifc
        from bimgraph.sim.scenarios import make

        model_path = out / MODEL_FILE
        write_ifc(make(scenario), model_path, schema="IFC4")
        freeze_ifc(model_path, scenario)
        model_ref = MODEL_FILE
    else:
        model_path = Path(opts.ifc).resolve()
        model_ref = str(model_path)
    # Slab tops tell where the storey's floor is (inside); wall face ids do not depend on them.
    stage("importing the model")
    plane_map, _ = import_ifc(model_path, cfg.bim.model_copy(update={"include_slabs": True}), log=log,
                              progress=lambda what, done, total: stage(f"importing the model: {what} {done}/{total}"))
    lap("import")
    stage("building the storey as built")

    rng_world, rng_clutter, rng_walk, rng_frontend, rng_observe, rng_align = (
        np.random.default_rng(s) for s in np.random.SeedSequence(opts.seed).spawn(6))
    storey = world.pick_storey(plane_map, sim.storey)
    planned = world.planned_elements(storey)
    as_built_cfg = {"office": sim.as_built_office, "site": sim.as_built_site, None: sim.as_built_ifc}[scenario]
    built, deviations = world.deviate(planned, {f.id: f.wall_guid for f in plane_map.faces}, as_built_cfg, rng_world)
    planned_walls = world.triangulate([e for e in planned if e.kind == "wall"])
    grid = occupancy.Grid.around(planned_walls.vertices[:, :2], sim.trajectory.grid_m)
    inside = occupancy.inside(grid, planned_walls, storey.floor_z, storey.floors)
    if not inside.any():
        raise InputError(f"{model_path.name}: storey {storey.name!r} has no room enclosed by walls")
    # Clutter is placed, and the walk planned, in the world as planned less the walls not built:
    # the same scenario with and without offsets and tilts then has the same clutter and walk.
    missing = {d.face_id for d in deviations if not d.built}
    level = [e for e in planned if e.face_id is None or e.face_id not in missing]
    items = clutter.furnish(level, storey.floor_z, grid, inside, KINDS[scenario or "ifc"], as_built_cfg,
                            sim.trajectory.clearance_m, rng_clutter)
    elements = built + items
    mesh = world.triangulate(elements)
    lap("world")

    stage("planning the walk")
    occupied = occupancy.obstacles(grid, world.triangulate(level + items), storey.floor_z)
    free, distance = occupancy.free_space(occupied, inside, grid.cell, sim.trajectory.clearance_m)
    walk = plan_trajectory(free, distance, grid, storey.floor_z, sim.trajectory, opts.keyframes, rng_walk)
    front = simulate_frontend(walk.T_B_C, sim.frontend, rng_frontend)
    T_B_S_init, yaw_error, shift = initial_alignment(front.T_B_S, sim.initial_rot_error_deg, sim.initial_trans_error_m, rng_align)
    lap("trajectory")
    stage("observing")

    camera = Camera(width=sim.width, height=sim.height, fx=sim.fx, fy=sim.fy,
                    cx=(sim.width - 1) / 2, cy=(sim.height - 1) / 2)
    renderer = DepthRenderer(mesh.vertices, mesh.triangles, mesh.element)
    stride = sim.observe.stride_px
    coarse = observe.coarse_camera(camera, stride)
    keyframes, gt_observations, gt_visible = [], [], []
    for k, (stamp, T_B_C, T_S_C) in enumerate(zip(walk.stamps, walk.T_B_C, front.T_S_C)):
        kf = Keyframe(index=k, stamp=round(float(stamp), 6), T_S_C=tuple(pose7(T_S_C)))
        depth, ids = renderer.render(coarse, T_B_C)
        detections, visible = observe.detect(depth, ids, coarse, T_B_C, elements, stride, sim.observe, rng_observe)
        if opts.sensor == "planes":
            kf.planes = [d.observation for d in detections]
            gt_observations.append([
                {"face_id": elements[d.element].face_id, "element": elements[d.element].name,
                 "kind": elements[d.element].kind, "plane_C": rounded(d.plane_C_true)} for d in detections])
        else:
            kf.depth, kf.rgb = _write_images(out, renderer, camera, T_B_C, stamp, cfg, rng_observe)
            gt_observations.append([])
        faces = {elements[e].face_id: n for e, n in sorted(visible.items()) if elements[e].face_id is not None}
        gt_visible.append({"index": k, "faces": faces})
        keyframes.append(kf)
        progress(k + 1, len(walk.stamps))
    lap("observe")

    fe_cfg = sim.frontend
    meta = SequenceMeta(
        name=f"{scenario or model_path.stem} seed {opts.seed}", model=model_ref, camera=camera, sensor=opts.sensor,
        gravity_aligned=fe_cfg.gravity_aligned,
        initial_alignment=InitialAlignment(T_B_S=tuple(pose7(T_B_S_init)), sigma_rot_deg=max(sim.initial_rot_error_deg),
                                           sigma_trans_m=max(sim.initial_trans_error_m)),
        simulated={
            "scenario": scenario, "ifc": None if scenario else model_ref, "seed": opts.seed, "sensor": opts.sensor,
            "keyframes": opts.keyframes, "storey": storey.name,
            "drift": {"configured": {"translation_drift_percent": 100 * fe_cfg.translation_drift,
                                     "yaw_drift_deg_per_m": fe_cfg.yaw_drift_deg_per_m,
                                     "scale_error_percent": 100 * fe_cfg.scale_error}, "measured": front.drift},
            "options": sim.model_dump(mode="json"),
            "depth_noise": cfg.depth_noise.model_dump(mode="json") if opts.sensor == "depth" else None,
        },
    )
    save_sequence(Sequence(root=out, meta=meta, keyframes=keyframes))
    if opts.sensor == "depth":
        _write_tum_lists(out, walk.stamps)
    write_groundtruth(out, GroundTruth(
        stamps=np.round(walk.stamps, 6), T_B_C=walk.T_B_C, T_B_S=front.T_B_S,
        extrinsic={"initial_alignment": {"T_B_S": pose7(T_B_S_init), "yaw_error_deg": rounded(yaw_error),
                                         "translation_error_m": rounded(shift)},
                   "drift": front.drift},
        observations=gt_observations, as_built=_as_built_record(storey, deviations, elements), visible=gt_visible))
    lap("write")
    return {
        "keyframes": len(keyframes), "planes": sum(len(kf.planes) for kf in keyframes),
        "elements": len(elements), "faces": len(deviations), "distance_m": walk.distance_m,
        "drift": front.drift, "timings_s": timings,
    }


def _image_name(stamp: float) -> str:
    return f"{stamp:.6f}.png"


def _write_images(out: Path, renderer, camera: Camera, T_B_C, stamp, cfg: Config, rng) -> tuple[str, str]:
    """Depth (16-bit, metres x depth_scale, sensor noise), a shaded colour image, and the
    element label image of the ideal render; returns the depth and colour paths."""
    import cv2

    from bimgraph.sim.render import add_depth_noise
    from bimgraph.sequence.tum_rgbd import write_depth_png

    depth, ids, cos_incidence = renderer.render(camera, T_B_C, with_incidence=True)
    noisy = add_depth_noise(depth, cfg.depth_noise, rng, cos_incidence)
    name = _image_name(stamp)
    write_depth_png(out / "depth" / name, noisy, camera.depth_scale)
    palette = (np.abs(np.sin(np.arange(1, max(int(ids.max()), 0) + 2)[:, None] * [12.9898, 78.233, 37.719])) * 160 + 60).astype(float)
    shade = 0.35 + 0.65 * cos_incidence
    rgb = np.where(ids[..., None] >= 0, palette[np.maximum(ids, 0)] * shade[..., None], 0).astype(np.uint8)
    for folder, image in [("rgb", rgb[..., ::-1]), (f"groundtruth/{LABELS_FOLDER}", (ids + 1).astype(np.uint16))]:
        (out / folder).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / folder / name), image)
    return f"depth/{name}", f"rgb/{name}"


def _write_tum_lists(out: Path, stamps) -> None:
    """depth.txt and rgb.txt as in the TUM RGB-D benchmark, so its loaders read the folder."""
    from bimgraph.sequence.tum_rgbd import write_image_list

    stamps = np.round(stamps, 6)
    for kind in ("depth", "rgb"):
        write_image_list(out / f"{kind}.txt", stamps, [f"{kind}/{_image_name(s)}" for s in stamps], kind)
