"""The BIM Collaboration Format file: one topic per deviating wall face, naming the wall's IFC
GlobalId and with a viewpoint from inside the room looking at the face (at its material, not at
a window in it: `bimgraph.deviations.viewpoint`), so that BIM tools
(BIMcollab, Solibri, BlenderBIM, Revit plug-ins) open the issue on the right wall; and one
topic naming the walls of a contest (one of them off plan, which one the data cannot tell),
one per room width off plan, naming its two walls, and one per wall thickness off plan."""

from __future__ import annotations

import datetime
import uuid
from pathlib import Path

import numpy as np
from bcf.geometry import camera_vectors_from_target_position
from bcf.v3 import model as mdl
from bcf.v3.bcfxml import BcfXml
from bcf.v3.visinfo import VisualizationInfoHandler, build_camera_from_vectors, build_components
from xsdata.models.datatype import XmlDateTime

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.report import DeviationsFile
from bimgraph.deviations.viewpoint import viewpoint
from bimgraph.files import ensure_folder, existing_file
from bimgraph.geometry import pose_from_tum

BCF_FILE = "deviations.bcf"


def _built(record) -> str:
    direction = "into the room" if record.offset_m >= 0 else "out of the room"
    return (f"{abs(record.offset_m) * 100:.1f} +/- {record.offset_sigma_m * 100:.1f} cm {direction} from plan "
            f"and tilted {record.tilt_deg:.2f} +/- {record.tilt_sigma_deg:.2f} deg")


def _describe(record, cfg: DeviationConfig) -> str:
    return (f"Wall face {record.face_id} of {record.wall_name or record.wall_guid} ({record.storey}) is built "
            f"{_built(record)}; tolerance +/-{cfg.tolerance_m * 100:.1f} cm and {cfg.tilt_tolerance_deg:.2f} deg. "
            f"Seen in {record.n_keyframes} keyframes.")


def _describe_contest(contested) -> str:
    def one(explanation) -> str:
        faces = " and ".join(f"face {f.face_id} of {f.wall_name or f.wall_guid} ({f.storey}) is built {_built(f)}"
                             for f in explanation.deviating) or "none of them is off beyond tolerance"
        return f"{faces} ({explanation.probability * 100:.0f} % likely)"

    return ("The scan shows that these walls are not all where the plan puts them, but not which one is off. "
            "Either " + ", or ".join(one(e) for e in contested) + ". Measuring between them on site tells which.")


def _describe_distance(subject: str, record, more: str, less: str, cfg: DeviationConfig) -> str:
    """A room width's or a wall thickness's description: `subject` measures ..., `more` or `less`."""
    change = record.built_m - record.planned_m
    return (f"{subject} measures {record.built_m:.3f} +/- {record.sigma_m:.3f} m between wall faces {record.faces[0]} and "
            f"{record.faces[1]}, planned {record.planned_m:.3f} m: {abs(change) * 100:.1f} cm {more if change > 0 else less} "
            f"(tolerance +/-{cfg.tolerance_m * 100:.1f} cm). Seen in {record.n_keyframes} keyframes or more.")


# the topic type and statuses of every topic, which BCF 3.0 wants listed in extensions.xml
_TYPE = "Issue"
_STATUSES = ["Open", "Closed"]


def _extensions(author: str) -> mdl.Extensions:
    """extensions.xml: the values the topics use, every list present (buildingSMART's schema
    wants all seven, empty or not)."""
    return mdl.Extensions(topic_types=mdl.ExtensionsTopicTypes(topic_type=[_TYPE]),
                          topic_statuses=mdl.ExtensionsTopicStatuses(topic_status=_STATUSES),
                          priorities=mdl.ExtensionsPriorities(), topic_labels=mdl.ExtensionsTopicLabels(),
                          users=mdl.ExtensionsUsers(user=[author]), snippet_types=mdl.ExtensionsSnippetTypes(),
                          stages=mdl.ExtensionsStages())


def _header(plane_map: PlaneMap) -> mdl.Header | None:
    """The model a topic is about (its file and IfcProject), by which BIM tools pick the model
    to open it on; None for a map that names neither (hand-written)."""
    if not plane_map.source and not plane_map.ifc_project:
        return None
    return mdl.Header(files=mdl.HeaderFiles(file=[mdl.File(filename=plane_map.source or None, ifc_project=plane_map.ifc_project or None,
                                                           is_external=True)]))


def write_bcf(deviations: DeviationsFile, plane_map: PlaneMap, path: Path, cfg: DeviationConfig,
              project_name: str = "bimgraph as-built deviations") -> int:
    """Write the BCF 3.0 file; returns the number of topics: one per deviating face, one for a
    contest (walls of which one is off plan, which one the data cannot tell), one per room
    width off plan (selecting both walls) and one per wall thickness off plan."""
    faces = plane_map.index
    # viewpoints are in the IFC file's world frame, in metres: B's pose in it, if B is not it
    T_W_B = np.eye(4) if plane_map.T_W_B is None else pose_from_tum(plane_map.T_W_B)
    bcf = BcfXml.create_new(project_name, extensions=_extensions(cfg.bcf_author))
    # the same project's reports merge into one project of a BIM tool, whose ids BCF keeps
    bcf.project_info.project.project_id = str(uuid.uuid5(uuid.NAMESPACE_URL, f"bimgraph:{plane_map.ifc_project or plane_map.source}"))
    created = XmlDateTime.from_datetime(datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0))
    header = _header(plane_map)

    def add_topic(title: str, description: str, face_id: str, guids: list[str]) -> None:
        face = plane_map.faces[faces[face_id]]
        topic = bcf.add_topic(title, description, cfg.bcf_author, topic_type=_TYPE, topic_status=_STATUSES[0])
        topic.topic.creation_date = created  # (bcf-client's is local time without a zone, which BCF reads as UTC)
        topic.header = header
        # Look at the face from inside its room, from half a metre above the point looked at.
        camera_B, target_B = viewpoint(plane_map, face, cfg.bcf_view_distance_m, 0.5)
        target_W = T_W_B[:3, :3] @ target_B + T_W_B[:3, 3]
        camera = build_camera_from_vectors(*camera_vectors_from_target_position(target_W, T_W_B[:3, :3] @ (camera_B - target_B)))
        info = mdl.VisualizationInfo(guid=str(uuid.uuid4()), components=build_components(*guids),
                                     perspective_camera=camera)
        topic.add_visinfo_handler(VisualizationInfoHandler(info))

    deviating = [record for record in deviations.faces if record.status == "deviating"]
    for record in deviating:
        add_topic(f"As-built deviation: {record.wall_name or record.face_id}", _describe(record, cfg),
                  record.face_id, [record.wall_guid])
    contested = [f for explanation in deviations.contested for f in explanation.deviating]
    if contested:
        names = list(dict.fromkeys(f.wall_name or f.face_id for f in contested))
        add_topic(f"Which wall is off plan: {' or '.join(names)}", _describe_contest(deviations.contested),
                  contested[0].face_id, list(dict.fromkeys(f.wall_guid for f in contested)))
    for width in (w for w in deviations.widths if w.status == "deviating"):
        room = width.space_name or width.space_guid
        walls = " and ".join(dict.fromkeys(plane_map.faces[faces[face]].wall_name or face for face in width.faces))
        add_topic(f"Room width off plan: {room}, between {walls}", _describe_distance(f"Room {room}", width, "wider", "narrower", cfg),
                  width.faces[0], list(dict.fromkeys(plane_map.faces[faces[face]].wall_guid for face in width.faces)))
    for thickness in (t for t in deviations.thicknesses if t.status == "deviating"):
        wall = thickness.wall_name or thickness.wall_guid
        add_topic(f"Wall thickness off plan: {wall}", _describe_distance(f"Wall {wall}", thickness, "thicker", "thinner", cfg),
                  thickness.faces[0], [thickness.wall_guid])
    path = Path(path)
    ensure_folder(path.parent)
    bcf.save(path)
    return len(bcf.topics)


def read_bcf_topics(path: Path) -> list[tuple[str, list[str]]]:
    """(title, selected IFC GlobalIds of its viewpoints) per topic of a BCF file."""
    path = existing_file(path)
    with BcfXml.load(path) as bcf:
        out = []
        for topic in bcf.topics.values():
            guids = [g for vp in topic.viewpoints.values() for g in (vp.get_selected_guids() or [])]
            out.append((topic.topic.title, guids))
        return out
