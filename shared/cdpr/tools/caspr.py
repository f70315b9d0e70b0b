"""``cdpr import caspr``: a CASPR model (its bodies and cables XML files) as the project's robot YAML.

CASPR (github.com/darwinlau/CASPR, Lau et al.) describes a cable robot in two XML files: ``*_bodies.xml``
(links: joint type, initial pose ``q_initial``, mass, centre of mass, inertia) and ``*_cables.xml`` (named cable
sets; each cable's force range and its two attachments, on link 0, the frame, and link 1, the platform). This
module reads single-rigid-body models — one link on a spatial (``SPATIAL_EULER_XYZ``), planar (``PLANAR_XY``,
``PLANAR_XZ``) or translational (``T_XYZ``) joint, cables from the frame straight to the platform, leaving the
frame at a point or over a rotating pulley (``base_rotating_pulley``) — into a robot file's data, and names in it
everything the model does not say and the import had to choose.

Frames. CASPR places the platform by its joint frame (q: the frame's position, then Euler XYZ angles, R =
Rx(a)·Ry(b)·Rz(c)) and gives each platform point either in that frame (``attachment_reference="joint"``) or from
the centre of mass (``"com"``). The robot file's platform frame is CASPR's joint frame: its points are b_joint (b +
c for ``"com"``, c the COM in the joint frame), ``platform.com`` is c, and ``home`` is q_initial's position and
rotation, so CASPR's q is a pose of the file's platform frame as it stands (``cdpr ik --pose X Y Z A B C --angles
xyz``). The inertia is taken about the COM (``ref="com"``; ``ref="joint"`` is moved to the COM with the
parallel-axis theorem).

Pulleys. CASPR's ``base_rotating_pulley`` (``BaseRotatingPulleyAttachment``) is a wheel of radius R that swivels
about the line through ``fixed_location`` F along ``cable_entry_vector`` v: the cable runs into the wheel at F along
v, the wheel's centre is C = F + R·e (e the unit vector from that line towards the platform point B, across v), the
cable leaves at the tangent point A (A = C + ρ²(B − C) − ρ√(1 − ρ²)·n × (B − C), ρ = R/|B − C|, n the unit normal
v × (B − F)) and the length is |B − A| plus the arc R·acos((F − C)·(A − C)/R²). That is the project's exit pulley
(cdpr.mechanics.pulley) with frame point F, ``axis`` v and ``radius`` R: the same centre, tangent point, free span
and force direction, and the same arc π − φ while it is at most a half-turn (φ ≥ 0: the platform point at least
2R from the swivel line, i.e. anywhere but under the wheel); beyond, CASPR's acos folds the arc back (2π − β for β),
the project's keeps growing with the wrap.
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

# CASPR joint type → (mode, plane)
_JOINTS: dict[str, tuple[str, str | None]] = {
    "SPATIAL_EULER_XYZ": ("spatial", None),
    "PLANAR_XY": ("planar", "xy"),
    "PLANAR_XZ": ("planar", "xz"),
    "T_XYZ": ("point_mass", None),
}
PAD = 0.05  # m: the frame box's half-height along an axis where every anchor lies in one plane
MAX_SPEED = 2.0  # m/s: cable speed limit, which CASPR's models do not give
BODIES, CABLES = "bodies_system", "cables"  # the root tags of CASPR's two files


class UnsupportedError(InputError):
    """A cable (set) in a well-formed CASPR file that the project cannot model: ``reason`` without the place."""

    def __init__(self, where: str, reason: str) -> None:
        super().__init__(f"{where}: {reason}")
        self.reason = reason


@dataclass
class CasprModel:
    """What the two files say, in the project's terms (the platform frame: CASPR's joint frame)."""

    name: str
    mode: str
    plane: str | None
    mass: float
    inertia: list[list[float]]  # about the COM
    com: list[float]  # the COM in CASPR's joint frame (the file's platform.com)
    home: list[float]  # the joint frame's position at q_initial
    home_angles: list[float]  # q_initial's angles, Euler XYZ
    reach: list[list[float]]  # positions the joint's range [q_min, q_max] spans (its corners' positions)
    default_set: str
    sets: dict[str, list[dict[str, Any]]]  # set id → cables {name, frame, platform, tmin, tmax, pulley}
    notes: list[str] = field(default_factory=list)


def _numbers(text: str | None, where: str, n: int | None = None) -> list[float]:
    try:
        values = [float(x) for x in (text or "").split()]
    except ValueError:
        raise InputError(f"{where}: expected numbers, got {text!r}") from None
    if (n is not None and len(values) != n) or not all(math.isfinite(v) for v in values):
        raise InputError(f"{where}: expected {n or 'some'} finite numbers, got {text!r}")
    return values


def _parse(path: Path, root_tag: str | None = None) -> ET.Element:
    try:
        root = ET.fromstring(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    except (ET.ParseError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid XML ({exc})") from None
    if root_tag is not None and root.tag != root_tag:
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
    root = _parse(path, BODIES)
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
    parent = link.findtext("parent/location")
    if parent is not None and any(_numbers(parent, f"{where}: parent location", 3)):
        raise InputError(f"{where}: parent location {' '.join(parent.split())}: cdpr imports a platform whose joint "
                         "frame is at q from the world's origin (parent location 0 0 0, as in CASPR's models)")
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


def _pulley(element: ET.Element, where: str) -> tuple[list[float], dict[str, Any]]:
    """A ``<base_rotating_pulley>``: (the frame point, F; the project's ``pulley: {radius, axis}``)."""
    fixed = _numbers(_text(element, "fixed_location", where), f"{where}: fixed_location", 3)
    radius = _numbers(_text(element, "pulley_radius", where), f"{where}: pulley_radius", 1)[0]
    axis = _numbers(_text(element, "cable_entry_vector", where), f"{where}: cable_entry_vector", 3)
    if radius < 0.0:
        raise InputError(f"{where}: pulley_radius must not be negative, got {radius:g}")
    if float(np.linalg.norm(axis)) < 1e-9:
        raise InputError(f"{where}: cable_entry_vector must not be zero (the direction the cable runs into the "
                         "pulley)")
    return fixed, {"radius": radius, "axis": axis}


def _cable(cable: ET.Element, where: str, number: int) -> dict[str, Any]:
    """One ``<cable_…>`` of a set as {name, type, reference, frame, platform, tmin, tmax, pulley};
    :class:`UnsupportedError` for a cable the project cannot model."""
    if cable.tag == "cable_passive_linear_spring":
        raise UnsupportedError(where, "a passive spring (<cable_passive_linear_spring>): cdpr's cables are all "
                                      "actuated, with tension limits")
    reference = cable.get("attachment_reference", "joint")
    if reference not in ("joint", "com"):
        raise InputError(f"{where}: attachment_reference {reference!r}: CASPR's are 'joint' and 'com'")
    attachments = cable.find("attachments")
    ends = [] if attachments is None else list(attachments)
    for end in ends:
        if end.tag == "screw_base_rotating_pulley":
            raise UnsupportedError(where, "a screw-drive rotating pulley (<screw_base_rotating_pulley>): its outlet "
                                          "travels along the winch drum from a hardware reading; cdpr imports fixed "
                                          "swivelling pulleys (<base_rotating_pulley>)")
        if end.tag not in ("attachment", "base_rotating_pulley"):
            raise UnsupportedError(where, f"an attachment <{end.tag}>: cdpr imports <attachment> and "
                                          "<base_rotating_pulley>")
    links = ["0" if e.tag == "base_rotating_pulley" else _text(e, "link", where).strip() for e in ends]
    if links != ["0", "1"] or ends[1].tag != "attachment":
        raise UnsupportedError(where, f"attached to links {', '.join(links) or 'none'}: cdpr imports cables that run "
                                      "from the frame (link 0) straight to the platform (link 1)")
    pulley = None
    if ends[0].tag == "base_rotating_pulley":
        frame, pulley = _pulley(ends[0], f"{where}: base_rotating_pulley")
    else:
        frame = _numbers(_text(ends[0], "location", where), f"{where}: frame location", 3)
    return {
        "name": cable.get("name") or f"cable {number}",
        "type": cable.tag,
        "reference": reference,
        "frame": frame,
        "platform": _numbers(_text(ends[1], "location", where), f"{where}: platform location", 3),
        "tmin": _numbers(_text(cable, "properties/force_min", where), f"{where}: force_min", 1)[0],
        "tmax": _numbers(_text(cable, "properties/force_max", where), f"{where}: force_max", 1)[0],
        "pulley": pulley,
    }


def read_cables(path: Path) -> tuple[str, dict[str, list[dict[str, Any]] | UnsupportedError]]:
    """(default set id, {set id: [{name, type, reference, frame, platform, tmin, tmax, pulley}], or the
    :class:`UnsupportedError` that keeps the set out}) of a cables file."""
    root = _parse(path, CABLES)
    sets: dict[str, list[dict[str, Any]] | UnsupportedError] = {}
    for cable_set in root.findall("cable_set"):
        set_id = cable_set.get("id") or f"set_{len(sets) + 1}"
        cables: list[dict[str, Any]] = []
        try:
            for i, cable in enumerate(cable_set):
                if cable.tag.startswith("cable_"):
                    where = f"{path}: cable set {set_id!r}, cable {cable.get('name') or i + 1!r}"
                    cables.append(_cable(cable, where, i + 1))
        except UnsupportedError as exc:
            sets[set_id] = exc
            continue
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
    default, read = read_cables(cables)
    if cable_set is not None and cable_set not in read:
        raise InputError(f"--cable-set: no cable set {cable_set!r} in {cables} (it has: {', '.join(read)})")
    chosen = cable_set or default
    sets = {k: v for k, v in read.items() if not isinstance(v, UnsupportedError)}
    if isinstance(problem := read[chosen], UnsupportedError):
        hint = f" (--cable-set picks another: {', '.join(sets)})" if sets and cable_set is None else ""
        raise InputError(f"{problem}{hint}")
    for set_id, v in read.items():
        if isinstance(v, UnsupportedError):
            notes.append(f"cable set {set_id!r} was left out: {v.reason}")
    position, angles = _pose(q, mode, plane)
    reach = [_pose(qq, mode, plane)[0] for qq in q_range]
    out_sets: dict[str, list[dict[str, Any]]] = {}
    for set_id, cables_of_set in sets.items():
        out = []
        for c in cables_of_set:
            b = np.array(c["platform"])
            b = b + com if c["reference"] == "com" else b  # "com": from the centre of mass; the file's: the joint's
            out.append({"name": c["name"], "frame": c["frame"], "platform": _clean(b), "tmin": c["tmin"],
                        "tmax": c["tmax"], "pulley": c["pulley"]})
        out_sets[set_id] = out
    if mode == "point_mass" and any(np.abs(np.array(c["platform"]) - com).max() > 1e-12
                                    for s in out_sets.values() for c in s):
        raise InputError(f"{bodies}: joint type 'T_XYZ' with platform points off the centre of mass: cdpr's "
                         "point_mass robots have every cable at the COM (the platform cannot turn)")
    kinds = sorted({c["type"] for s in sets.values() for c in s} - {"cable_ideal"})
    if kinds:
        notes.append(f"cable types {', '.join(kinds)} were read as ideal cables (straight, massless, inextensible)")
    over = [k for k, s in out_sets.items() if any(c["pulley"] is not None for c in s)]
    if over:
        notes.append(f"the rotating pulleys (base_rotating_pulley) of cable set{'s' if len(over) > 1 else ''} "
                     f"{', '.join(map(repr, over))} are exit pulleys: frame = its fixed_location, pulley radius = its "
                     "pulley_radius, axis = its cable_entry_vector (the same geometry, docs/robots.md)")
    if np.any(com != 0.0):
        notes.append(f"the platform frame is CASPR's joint frame (its points, home and poses as CASPR gives them); "
                     f"the centre of mass is at {_clean(com)} in it (platform.com)")
    if mode == "planar" and np.ndim(J) == 2:
        n = 2 if plane == "xy" else 1
        notes.append(f"planar: the moment about the plane's normal is CASPR's I{'xyz'[n] * 2} = {J[n, n]:g} kg·m²")
    return CasprModel(name, mode, plane, mass, J.tolist(), _clean(com), _clean(position), list(angles), reach,
                      chosen, out_sets, notes)


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
    com = np.array(model.com)
    home_com = np.array(model.home) + angles_to_matrix("xyz", model.home_angles) @ com
    anchors = np.array([c["frame"] for c in everything] + [model.home, home_com] + model.reach)
    low, high = anchors.min(axis=0), anchors.max(axis=0)
    flat = high - low < 1e-9
    low, high = np.where(flat, low - PAD, low), np.where(flat, high + PAD, high)
    wrap = max([math.pi * c["pulley"]["radius"] for c in everything if c["pulley"] is not None], default=0.0)
    max_length = math.ceil((float(np.linalg.norm(high - low)) + wrap) * 10.0) / 10.0
    points = np.array([c["platform"] for c in everything]) - com
    size = np.maximum(2.0 * np.abs(points).max(axis=0), 0.02)  # centred on the COM, every point on or in it
    shape = {"type": "sphere", "size": [0.05]} if model.mode == "point_mass" else {"type": "box",
                                                                                 "size": _clean(size)}

    def cable(c: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {"frame": c["frame"], "platform": c["platform"]}
        if c["tmin"] != tmin:
            out["tmin"] = c["tmin"]
        if c["tmax"] != tmax:
            out["tmax"] = c["tmax"]
        if c["pulley"] is not None:
            out["pulley"] = c["pulley"]
        return out

    assumed = [
        f"the shape (a {'sphere' if model.mode == 'point_mass' else 'box about the COM through the farthest points'})",
        "the frame box (around the anchors, the home position and the joint's q_min..q_max"
        + (f"; ±{PAD} m where these lie in a plane)" if flat.any() else ")"),
        f"max_length (the frame box's diagonal{' and a half-turn of the largest pulley' if wrap else ''}, "
        f"{max_length:g} m)",
        f"max_speed ({MAX_SPEED:g} m/s)",
        "no damping",
    ]
    data: dict[str, Any] = {
        "name": name or _slug(model.name),
        "description": f"CASPR's platform link {model.name!r}, imported (cable set {model.default_set!r}; "
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
    if np.any(com != 0.0):
        data["platform"]["com"] = model.com
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


# ------------------------------------------------------------------------------------------------
# Which files: two in either order, a model's folder, or a folder of several models


@dataclass(frozen=True)
class ModelFiles:
    """One CASPR model's two files; ``name`` is their common prefix (``CAROCA`` of ``CAROCA_bodies.xml``)."""

    name: str
    bodies: Path
    cables: Path

    @property
    def origin(self) -> str:
        """How the robot file's ``source`` names the two files."""
        same = self.bodies.parent == self.cables.parent
        return f"{self.bodies.name} + {self.cables.name}" if same else f"{self.bodies} + {self.cables}"


def _prefix(path: Path, kind: str) -> str:
    return path.name[: -len(f"_{kind}.xml")] if path.name.endswith(f"_{kind}.xml") else path.stem


def find_models(paths: list[Path], model: str | None = None) -> list[ModelFiles]:
    """The models to import: from BODIES.xml and CABLES.xml (either order: told apart by their root tags), or from
    a folder holding one model (one ``*_bodies.xml`` and one ``*_cables.xml``) or several (``NAME_bodies.xml`` with
    ``NAME_cables.xml`` each; ``model``: only NAME)."""
    if len(paths) == 1 and paths[0].is_dir():
        return _folder_models(paths[0], model)
    if len(paths) == 1:
        what = "is a file" if paths[0].exists() else "does not exist"
        raise InputError(f"{paths[0]}: {what}: give a CASPR model folder, or its BODIES.xml and CABLES.xml")
    if len(paths) != 2:
        raise InputError(f"{len(paths)} paths given: give BODIES.xml and CABLES.xml (either order), or a CASPR model "
                         "folder")
    if model is not None:
        raise InputError("--model picks one of a folder's models: the two files given are one model")
    for p in paths:
        if p.is_dir():
            raise InputError(f"{p}: a folder: give BODIES.xml and CABLES.xml (either order), or the folder alone")
    tags = [_parse(p).tag for p in paths]
    if sorted(tags) != sorted([BODIES, CABLES]):
        found = " and ".join(f"{p.name} <{t}>" for p, t in zip(paths, tags, strict=True))
        raise InputError(f"{found}: a CASPR model is a bodies file (<{BODIES}>) and a cables file (<{CABLES}>)")
    bodies, cables = paths if tags[0] == BODIES else paths[::-1]
    return [ModelFiles(_prefix(bodies, "bodies"), bodies, cables)]


def _folder_models(folder: Path, model: str | None) -> list[ModelFiles]:
    bodies, cables = sorted(folder.glob("*_bodies.xml")), sorted(folder.glob("*_cables.xml"))
    if not bodies or not cables:
        raise InputError(f"{folder}: no CASPR model in it (a model is NAME_bodies.xml and NAME_cables.xml; found "
                         f"{len(bodies)} *_bodies.xml and {len(cables)} *_cables.xml)")
    if len(bodies) == 1 and len(cables) == 1:  # one model, whatever its files' prefixes
        found = [ModelFiles(_prefix(bodies[0], "bodies"), bodies[0], cables[0])]
    else:
        by_name = {_prefix(c, "cables"): c for c in cables}
        names = {_prefix(b, "bodies") for b in bodies}
        for b in bodies:
            if _prefix(b, "bodies") not in by_name:
                raise InputError(f"{folder}: {b.name} has no {_prefix(b, 'bodies')}_cables.xml beside it (each model "
                                 "of a folder is NAME_bodies.xml and NAME_cables.xml)")
        for name, c in by_name.items():
            if name not in names:
                raise InputError(f"{folder}: {c.name} has no {name}_bodies.xml beside it (each model of a folder is "
                                 "NAME_bodies.xml and NAME_cables.xml)")
        found = [ModelFiles(_prefix(b, "bodies"), b, by_name[_prefix(b, "bodies")]) for b in bodies]
    if model is None:
        return found
    chosen = [m for m in found if m.name == model]
    if not chosen:
        raise InputError(f"--model: no model {model!r} in {folder} (it has: {', '.join(m.name for m in found)})")
    return chosen


# ------------------------------------------------------------------------------------------------
# The command


@dataclass
class Imported:
    """One imported model: its files, the robot file's content and text, and what the command reports."""

    files: ModelFiles
    data: dict[str, Any]
    text: str
    report: dict[str, Any]


def import_model(files: ModelFiles, cable_set: str | None = None, name: str | None = None,
                 home: tuple[float, float, float] | None = None) -> Imported:
    """A model as a robot file, loaded as every robot is before it is written (an :class:`InputError` if it cannot
    be: a home pose its cables cannot hold, with the way out)."""
    from cdpr.config.robot import robot_from_data

    model = read_model(files.bodies, files.cables, cable_set)
    if home is not None:
        if not all(np.isfinite(home)):
            raise InputError("--home: X, Y and Z must be finite")
        model.notes.append(f"home: {list(home)} given on the command line (CASPR's q_initial puts the platform frame "
                           f"at {model.home})")
        model.home = [float(x) for x in home]
    data = robot_data(model, name or _slug(files.name), files.origin)  # the model's name, not its link's ("link_1")
    try:
        robot = robot_from_data(data, f"{data['name']} (imported from {files.origin})")
    except InputError as exc:
        if ": home: " not in str(exc):
            raise
        reason = str(exc).split("; `cdpr robots ", 1)[0]  # (no file yet for `cdpr robots FILE --find-home`)
        raise InputError(f"{reason} (--home X Y Z chooses another home position)") from None
    report = {"model": files.name, "robot": robot.name, "mode": robot.mode, "cables": robot.m,
              "cable_set": robot.cable_set, "cable_sets": [model.default_set, *data.get("cable_sets", {})],
              "notes": model.notes}
    return Imported(files, data, robot_yaml(data, files.origin), report)


def import_caspr(paths: list[Path], model: str | None = None, cable_set: str | None = None, name: str | None = None,
                 home: tuple[float, float, float] | None = None,
                 output: str | None = None) -> tuple[list[dict[str, Any]], str | None]:
    """``cdpr import caspr``: every model ``paths`` hold (or ``model``) imported and written — to ``output`` (a file,
    a folder: an existing one or a path ending in /, or ``-``: stdout), else NAME.yaml each — or none of them when
    one cannot be. (What the command reports per robot, and the robot file's text when it goes to stdout.)"""
    found = find_models(paths, model)
    folder = output is not None and output != "-" and (Path(output).is_dir() or output.endswith(("/", "\\")))
    if len(found) > 1:
        names = ", ".join(m.name for m in found)
        for flag, value in (("--cable-set", cable_set), ("--name", name), ("--home", home)):
            if value is not None:
                raise InputError(f"{flag}: {paths[0]} holds {len(found)} models ({names}): --model NAME picks the one "
                                 f"{flag} is for")
        if output is not None and not folder:
            raise InputError(f"-o: {paths[0]} holds {len(found)} models ({names}): -o names a folder for their robot "
                             "files (an existing one, or ending in /), or --model NAME picks one")
    imported = []
    for files in found:
        try:
            imported.append(import_model(files, cable_set, name, home))
        except InputError as exc:
            if len(found) == 1:
                raise
            raise InputError(f"{exc} (nothing written; --model NAME imports another of the folder's models alone)") \
                from None
    robots = Counter(i.data["name"] for i in imported)
    if (twice := [n for n, k in robots.items() if k > 1]):
        same = ", ".join(i.files.name for i in imported if i.data["name"] == twice[0])
        raise InputError(f"{paths[0]}: models {same} are all named {twice[0]!r}: import them one by one (--model NAME "
                         "--name ROBOT)")
    if output == "-":
        return [imported[0].report], imported[0].text
    targets = [Path(output or "") / f"{i.data['name']}.yaml" if folder else Path(output or f"{i.data['name']}.yaml")
               for i in imported]
    for i, target in zip(imported, targets, strict=True):
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(i.text, encoding="utf-8")
        except OSError as exc:
            raise InputError(f"-o: cannot write {target}: {exc.strerror or exc}") from None
        i.report = {"robot": i.report["robot"], "file": str(target), **i.report}
    return [i.report for i in imported], None


def robot_yaml(data: dict[str, Any], origin: str, header: str | None = None) -> str:
    """The robot file's text: a header (default: naming the CASPR import of ``origin``), short lists (points,
    limits) and cables on one line."""
    import yaml

    class Dumper(yaml.SafeDumper):
        pass

    def short_list(dumper: Any, value: list[Any]) -> Any:
        flow = all(isinstance(v, int | float) for v in value)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", value, flow_style=flow)

    def small_map(dumper: Any, value: dict[str, Any]) -> Any:
        flow = ("frame" in value and "platform" in value) or "radius" in value  # a cable, its pulley: one line
        return dumper.represent_mapping("tag:yaml.org,2002:map", value, flow_style=flow)

    Dumper.add_representer(list, short_list)
    Dumper.add_representer(dict, small_map)
    body = yaml.dump(data, Dumper=Dumper, sort_keys=False, allow_unicode=True, width=110)
    if header is None:
        header = f"Imported from CASPR ({origin}) by `cdpr import caspr`: what it assumed is in `source`."
    return f"# {header}\n{body}"
