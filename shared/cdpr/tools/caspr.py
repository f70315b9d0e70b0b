"""``cdpr import caspr``: a CASPR model (its bodies and cables XML files) as the project's robot YAML.

CASPR (github.com/darwinlau/CASPR, Lau et al.) describes a cable robot in two XML files: ``*_bodies.xml``
(links: joint type, initial pose ``q_initial``, mass, centre of mass, inertia) and ``*_cables.xml`` (named cable
sets; each cable's force range and its two attachments, on link 0, the frame, and link 1, the platform). This
module reads single-rigid-body models — one link on a spatial (``SPATIAL_EULER_XYZ``), planar (``PLANAR_XY``,
``PLANAR_XZ``) or translational (``T_XYZ``) joint, cables from the frame straight to the platform — into a robot
file's data, and names in it everything the model does not say and the import had to choose.

Frames. CASPR places the platform by its joint frame (``q_initial``, Euler XYZ: R = Rx(a)·Ry(b)·Rz(c)) and gives
each platform point either in that frame (``attachment_reference="joint"``) or from the centre of mass
(``"com"``); the project's platform frame is at the centre of mass. So b_i = b_joint − c (c the COM in the joint
frame) and the home position is q + R·c: every cable length and every column of W at a pose is CASPR's at the
matching joint pose. The inertia is taken about the COM (``ref="com"``; ``ref="joint"`` is moved to the COM
with the parallel-axis theorem).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cdpr.errors import InputError
from cdpr.mechanics.rotation import angles_to_matrix

# CASPR joint type → (mode, plane, the q entries of the position, of the angles)
_JOINTS: dict[str, tuple[str, str | None]] = {
    "SPATIAL_EULER_XYZ": ("spatial", None),
    "PLANAR_XY": ("planar", "xy"),
    "PLANAR_XZ": ("planar", "xz"),
    "T_XYZ": ("point_mass", None),
}
PAD = 0.05  # m: the frame box's half-height along an axis where every anchor lies in one plane
MAX_SPEED = 2.0  # m/s: cable speed limit, which CASPR's models do not give


@dataclass
class CasprModel:
    """What the two files say, in the project's terms (frame at the COM)."""

    name: str
    mode: str
    plane: str | None
    mass: float
    inertia: list[list[float]]
    com: list[float]  # the COM in CASPR's joint frame (what b_i and the home position were shifted by)
    home: list[float]  # COM position at q_initial
    home_angles: list[float]  # q_initial's angles, Euler XYZ
    reach: list[list[float]]  # positions the joint's range [q_min, q_max] spans (its corners' positions)
    default_set: str
    sets: dict[str, list[dict[str, Any]]]  # set id → cables {name, frame, platform, tmin, tmax}
    notes: list[str] = field(default_factory=list)


def _numbers(text: str | None, where: str, n: int | None = None) -> list[float]:
    try:
        values = [float(x) for x in (text or "").split()]
    except ValueError:
        raise InputError(f"{where}: expected numbers, got {text!r}") from None
    if (n is not None and len(values) != n) or not all(math.isfinite(v) for v in values):
        raise InputError(f"{where}: expected {n or 'some'} finite numbers, got {text!r}")
    return values


def _parse(path: Path, root_tag: str) -> ET.Element:
    try:
        root = ET.fromstring(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    except ET.ParseError as exc:
        raise InputError(f"{path}: not valid XML ({exc})") from None
    if root.tag != root_tag:
        raise InputError(f"{path}: a CASPR {root_tag} file starts with <{root_tag}>, this one with <{root.tag}>")
    return root


def _text(element: ET.Element, tag: str, where: str) -> str:
    found = element.find(tag)
    if found is None or found.text is None:
        raise InputError(f"{where}: missing <{tag}>")
    return found.text


def read_bodies(path: Path) -> tuple[str, str, str | None, float, np.ndarray, np.ndarray, list[float], list[str],
                                     list[list[float]]]:
    """(name, mode, plane, mass, inertia about the COM (3×3), COM in the joint frame, q_initial, notes, the joint's
    range [q_min, q_max] where the file gives it)."""
    root = _parse(path, "bodies_system")
    links = root.findall("links/*")
    if len(links) != 1 or links[0].tag != "link_rigid":
        kinds = ", ".join(sorted({link.tag for link in links})) or "none"
        raise InputError(f"{path}: a CASPR model with {len(links)} link(s) ({kinds}): cdpr imports single-rigid-body "
                         "models only (one <link_rigid>, the platform)")
    link = links[0]
    where = f"{path}: link {link.get('num', '1')}"
    joint = link.find("joint")
    if joint is None:
        raise InputError(f"{where}: missing <joint>")
    kind = joint.get("type", "")
    if kind not in _JOINTS:
        raise InputError(f"{where}: joint type {kind!r}: cdpr imports {', '.join(_JOINTS)} (a platform on a "
                         "spatial, planar or translational joint)")
    mode, plane = _JOINTS[kind]
    n_q = {"spatial": 6, "planar": 3, "point_mass": 3}[mode]
    q = _numbers(joint.get("q_initial"), f"{where}: q_initial", n_q)
    q_range = [_numbers(joint.get(k), f"{where}: {k}", n_q) for k in ("q_min", "q_max") if joint.get(k) is not None]
    physical = link.find("physical")
    if physical is None:
        raise InputError(f"{where}: missing <physical>")
    mass = _numbers(_text(physical, "mass", where), f"{where}: mass", 1)[0]
    com = np.array(_numbers(_text(physical, "com_location", where), f"{where}: com_location", 3))
    inertia_el = physical.find("inertia")
    if inertia_el is None:
        raise InputError(f"{where}: missing <inertia>")
    moments = {k: _numbers(_text(inertia_el, k, where), f"{where}: inertia {k}", 1)[0]
               for k in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")}
    J = np.array([[moments["Ixx"], moments["Ixy"], moments["Ixz"]],
                  [moments["Ixy"], moments["Iyy"], moments["Iyz"]],
                  [moments["Ixz"], moments["Iyz"], moments["Izz"]]])
    notes = []
    if inertia_el.get("ref", "com") == "joint":  # about the joint frame's origin: move it to the COM
        J = J - mass * (float(com @ com) * np.eye(3) - np.outer(com, com))
        notes.append("the inertia was given about the joint frame (ref=\"joint\"): moved to the centre of mass")
    return link.get("name", path.stem), mode, plane, mass, J, com, q, notes, q_range


def read_cables(path: Path) -> tuple[str, dict[str, list[dict[str, Any]]]]:
    """(default set id, {set id: [{name, reference, frame, platform, tmin, tmax}]}) of a cables file."""
    root = _parse(path, "cables")
    sets: dict[str, list[dict[str, Any]]] = {}
    for cable_set in root.findall("cable_set"):
        set_id = cable_set.get("id") or f"set_{len(sets) + 1}"
        cables = []
        for i, cable in enumerate(cable_set):
            where = f"{path}: cable set {set_id!r}, cable {cable.get('name') or i + 1!r}"
            if not cable.tag.startswith("cable_"):
                continue
            ends = cable.findall("attachments/attachment")
            links = [_text(e, "link", where).strip() for e in ends]
            if links != ["0", "1"]:
                raise InputError(f"{where}: attached to links {', '.join(links)}: cdpr imports cables that run from "
                                 "the frame (link 0) straight to the platform (link 1)")
            cables.append({
                "name": cable.get("name") or f"cable {i + 1}",
                "type": cable.tag,
                "reference": cable.get("attachment_reference", "joint"),
                "frame": _numbers(_text(ends[0], "location", where), f"{where}: frame location", 3),
                "platform": _numbers(_text(ends[1], "location", where), f"{where}: platform location", 3),
                "tmin": _numbers(_text(cable, "properties/force_min", where), f"{where}: force_min", 1)[0],
                "tmax": _numbers(_text(cable, "properties/force_max", where), f"{where}: force_max", 1)[0],
            })
        if not cables:
            raise InputError(f"{path}: cable set {set_id!r} has no cables")
        sets[set_id] = cables
    if not sets:
        raise InputError(f"{path}: no <cable_set>")
    default = root.get("default_cable_set") or next(iter(sets))
    if default not in sets:
        raise InputError(f"{path}: default_cable_set {default!r} is not one of its sets ({', '.join(sets)})")
    return default, sets


def read_model(bodies: Path, cables: Path, cable_set: str | None = None) -> CasprModel:
    """A CASPR model's two files, in the project's terms (see the module docstring)."""
    name, mode, plane, mass, J, com, q, notes, q_range = read_bodies(bodies)
    default, sets = read_cables(cables)
    if cable_set is not None and cable_set not in sets:
        raise InputError(f"--cable-set: no cable set {cable_set!r} in {cables} (it has: {', '.join(sets)})")
    position, angles = _pose(q, mode, plane)
    reach = [_pose(qq, mode, plane)[0] for qq in q_range]
    R = angles_to_matrix("xyz", angles)
    home = np.array(position) + R @ com
    out_sets: dict[str, list[dict[str, Any]]] = {}
    for set_id, cables_of_set in sets.items():
        out = []
        for c in cables_of_set:
            b = np.array(c["platform"])
            b = b - com if c["reference"] == "joint" else b  # "com": already from the centre of mass
            out.append({"name": c["name"], "frame": c["frame"], "platform": _clean(b), "tmin": c["tmin"],
                        "tmax": c["tmax"]})
        out_sets[set_id] = out
    if mode == "point_mass" and any(np.abs(c["platform"]).max() > 1e-12 for s in out_sets.values() for c in s):
        raise InputError(f"{bodies}: joint type 'T_XYZ' with platform points off the centre of mass: cdpr's "
                         "point_mass robots have every cable at the COM (the platform cannot turn)")
    kinds = sorted({c["type"] for s in sets.values() for c in s} - {"cable_ideal"})
    if kinds:
        notes.append(f"cable types {', '.join(kinds)} were read as ideal cables (straight, massless, inextensible)")
    if np.any(com != 0.0):
        notes.append(f"the centre of mass is at {_clean(com)} in CASPR's joint frame: platform points (given "
                     "from the joint frame) and the home position are taken from the COM")
    if mode == "planar" and np.ndim(J) == 2:
        n = 2 if plane == "xy" else 1
        notes.append(f"planar: the moment about the plane's normal is CASPR's I{'xyz'[n] * 2} = {J[n, n]:g} kg·m²")
    return CasprModel(name, mode, plane, mass, J.tolist(), _clean(com), _clean(home), list(angles), reach,
                      cable_set or default, out_sets, notes)


def _pose(q: list[float], mode: str, plane: str | None) -> tuple[list[float], list[float]]:
    """A joint's coordinates → (position of its frame, Euler XYZ angles)."""
    if mode == "spatial":
        return q[:3], q[3:]
    if mode == "planar":  # PLANAR_XY: [x, y, θz]; PLANAR_XZ: [x, z, θy]
        if plane == "xy":
            return [q[0], q[1], 0.0], [0.0, 0.0, q[2]]
        return [q[0], 0.0, q[1]], [0.0, q[2], 0.0]
    return q, [0.0, 0.0, 0.0]


def _clean(v: np.ndarray | list[float]) -> list[float]:
    """Plain floats, −0.0 as 0.0 (for YAML)."""
    return [float(x) + 0.0 for x in np.asarray(v, dtype=float)]


def _slug(text: str) -> str:
    out = "".join(ch.lower() if ch.isalnum() else "_" for ch in text).strip("_")
    while "__" in out:
        out = out.replace("__", "_")
    return out or "caspr_robot"


def robot_data(model: CasprModel, name: str | None, origin: str) -> dict[str, Any]:
    """The robot file's content for ``model`` (its chosen set as ``cables``, the others as ``cable_sets``)."""
    cables = model.sets[model.default_set]
    everything = [c for s in model.sets.values() for c in s]
    common = lambda key: Counter(c[key] for c in everything).most_common(1)[0][0]  # noqa: E731
    tmin, tmax = common("tmin"), common("tmax")
    anchors = np.array([c["frame"] for c in everything] + [model.home] + model.reach)
    low, high = anchors.min(axis=0), anchors.max(axis=0)
    flat = high - low < 1e-9
    low, high = np.where(flat, low - PAD, low), np.where(flat, high + PAD, high)
    max_length = math.ceil(float(np.linalg.norm(high - low)) * 10.0) / 10.0
    points = np.array([c["platform"] for c in everything])
    size = np.maximum(2.0 * np.abs(points).max(axis=0), 0.02)  # centred on the COM, every point on or in it
    shape = {"type": "sphere", "size": [0.05]} if model.mode == "point_mass" else {"type": "box",
                                                                                 "size": _clean(size)}

    def cable(c: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {"frame": c["frame"], "platform": c["platform"]}
        if c["tmin"] != tmin:
            out["tmin"] = c["tmin"]
        if c["tmax"] != tmax:
            out["tmax"] = c["tmax"]
        return out

    assumed = [
        f"the shape (a {'sphere' if model.mode == 'point_mass' else 'box about the COM through the farthest points'})",
        "the frame box (around the anchors, the home position and the joint's q_min..q_max"
        + (f"; ±{PAD} m where these lie in a plane)" if flat.any() else ")"),
        f"max_length (the frame box's diagonal, {max_length:g} m)",
        f"max_speed ({MAX_SPEED:g} m/s)",
        "no damping",
    ]
    data: dict[str, Any] = {
        "name": name or _slug(model.name),
        "description": f"{model.name}, imported from CASPR (cable set {model.default_set!r}; "
                       f"{len(model.sets)} set(s) in the file).",
        "source": f"CASPR model {origin}, imported by cdpr import caspr. Assumed (CASPR does not give them): "
                  + "; ".join(assumed) + ". " + " ".join(n[0].upper() + n[1:] + "." for n in model.notes),
        "mode": model.mode,
    }
    if model.plane is not None:
        data["plane"] = model.plane
    n = {"xy": 2, "xz": 1}.get(model.plane or "")
    data["platform"] = {"mass": model.mass,
                        "inertia": float(model.inertia[n][n]) if n is not None else model.inertia,
                        "shape": shape}
    data["limits"] = {"tmin": tmin, "tmax": tmax, "max_length": max_length, "max_speed": MAX_SPEED}
    data["cables"] = [cable(c) for c in cables]
    data["cable_set"] = model.default_set
    others = {k: [cable(c) for c in v] for k, v in model.sets.items() if k != model.default_set}
    if others:
        data["cable_sets"] = others
    data["home"] = {"position": model.home, "rpy": _rpy(model.home_angles)}
    data["frame_box"] = {"min": _clean(low), "max": _clean(high)}
    return data


def _rpy(euler_xyz: list[float]) -> list[float]:
    """CASPR's Euler XYZ angles as the roll-pitch-yaw of the same rotation (R = Rz(yaw)·Ry(pitch)·Rx(roll))."""
    R = angles_to_matrix("xyz", euler_xyz)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return _clean([roll, pitch, yaw])


def find_files(paths: list[Path]) -> tuple[Path, Path]:
    """(bodies, cables) from the two files, or from a model folder holding ``*_bodies.xml`` and ``*_cables.xml``."""
    if len(paths) == 1 and paths[0].is_dir():
        folder = paths[0]
        bodies, cables = sorted(folder.glob("*_bodies.xml")), sorted(folder.glob("*_cables.xml"))
        if len(bodies) != 1 or len(cables) != 1:
            raise InputError(f"{folder}: a CASPR model folder holds one *_bodies.xml and one *_cables.xml "
                             f"(found {len(bodies)} and {len(cables)})")
        return bodies[0], cables[0]
    if len(paths) != 2:
        raise InputError("give BODIES.xml CABLES.xml, or a CASPR model folder")
    return paths[0], paths[1]
