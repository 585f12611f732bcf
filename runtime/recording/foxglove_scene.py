"""Foxglove views of a run: ``foxglove.SceneUpdate`` messages derived from the raw ones (docs/recording.md).

Pure Python, no foxglove-sdk needed: the recorder (``runtime.recording.mcap_log``) writes these
scenes as extra ``json`` channels next to the raw ``msgpack`` ones, and
``runtime.recording.foxglove_live.LiveView`` sends the same JSON to the Foxglove app live.

Topics (each a ``foxglove.SceneUpdate``, frame ``world``, metres, z = 0):

* ``/foxglove/estimated``: per ``EstimateMessage``, one entity per robot (id
  ``estimated/<robot>``): a green sphere at the estimated position and the robot id as a
  label; a robot that is an anchor in the estimate's step (not in the moving group of
  the current ``PlanMessage`` for that step) is dark green and has a dark ring around it.
* ``/foxglove/true``: per ``TruthSetMessage`` (one per step: every robot's true pose),
  entities ``true/<robot>``: blue spheres. Without truth sets (a stream of single
  ``TruthMessage``s), the latest truths are drawn with each ``EstimateMessage`` instead.
  With bodies (the run's ``model.robot_radius_m`` > 0), each true robot is a flat blue disc of
  the true body radius instead (``foxglove.CylinderPrimitive``, docs/bodies.md).
* ``/foxglove/contacts``: per ``ContactMessage``, a red ring of the body radius midway between
  the two robots at their closest and a label ``a-b`` (entity ``contact/<step>/<a>-<b>``, kept).
* ``/foxglove/desired``: per ``PlanMessage``, the configuration it plans for, taken from
  the trajectory (``{"robots", "configurations"}``, docs/trajectory.md): one entity per
  robot (``desired/<robot>``), a red sphere and the id; and the entity ``legend``: one
  sample of every marker with what it means, above the top-left corner of the trajectory.

Entities with the same id replace the previous ones, so each message costs O(its robots).
Scenes come out as compact UTF-8 JSON bytes, built from text fragments (cheap enough to
derive two full-swarm scenes per step while recording); ``json.loads`` gives the dict.
``SceneDeriver`` holds the little state needed (the trajectory, the latest plan and truths).
The JSON schema is the official one (``SCENE_UPDATE_SCHEMA``, see ``_SCENE_UPDATE_SCHEMA_TEXT``).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

from runtime.wire.messages import ContactMessage, EstimateMessage, Message, PlanMessage, RobotEvent, TruthMessage, TruthSetMessage

SCHEMA_NAME = "foxglove.SceneUpdate"
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
FRAME = "world"
TOPIC_PREFIX = "/foxglove/"
TOPIC_ESTIMATED = "/foxglove/estimated"
TOPIC_TRUE = "/foxglove/true"
TOPIC_DESIRED = "/foxglove/desired"
TOPIC_CONTACTS = "/foxglove/contacts"
TOPICS = (TOPIC_ESTIMATED, TOPIC_TRUE, TOPIC_DESIRED, TOPIC_CONTACTS)



def color(r: float, g: float, b: float, a: float) -> str:
    """The JSON of a ``foxglove.Color`` (each channel in [0, 1])."""
    return f'{{"r":{float(r)!r},"g":{float(g)!r},"b":{float(b)!r},"a":{float(a)!r}}}'


# colours and sizes (m): the paper's figures use desired red, estimated green, true blue
GREEN = color(0.1, 0.75, 0.2, 0.9)
DARK_GREEN = color(0.0, 0.35, 0.1, 1.0)
BLUE = color(0.15, 0.35, 0.95, 0.9)
RED = color(0.9, 0.1, 0.1, 0.6)
WHITE = color(1.0, 1.0, 1.0, 1.0)
GREY = color(0.5, 0.5, 0.5, 0.9)
SPHERE_M = 0.05
TRUE_SPHERE_M = 0.04
ANCHOR_SPHERE_M = 0.065
RING_RADIUS_M = 0.05
RING_THICKNESS_M = 0.006
RING_POINTS = 16
LABEL_PX = 12.0
LABEL_DZ_M = 0.05
DISC_HEIGHT_M = 0.004  # a body's disc (cylinder) height

# The official JSON schema of foxglove.SceneUpdate: foxglove/foxglove-sdk,
# schemas/jsonschema/SceneUpdate.json at commit ca8a1ced73b2737d03e2e3f282b57359a1a4cb72,
# with the "description" and "$comment" keys removed (structure, titles, enums and
# required lists unchanged). foxglove-sdk itself ships only the protobuf schema.
_SCENE_UPDATE_SCHEMA_TEXT = (
    '{"title":"foxglove.SceneUpdate","type":"object","properties":{"deletions":{"type":"array","items":{"'
    'title":"foxglove.SceneEntityDeletion","type":"object","properties":{"timestamp":{"type":"object","ti'
    'tle":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,'
    '"maximum":999999999}}},"type":{"title":"foxglove.SceneEntityDeletionType","oneOf":[{"title":"MATCHIN'
    'G_ID","const":0},{"title":"ALL","const":1}]},"id":{"type":"string"}},"required":["timestamp","type",'
    '"id"]}},"entities":{"type":"array","items":{"title":"foxglove.SceneEntity","type":"object","properti'
    'es":{"timestamp":{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},'
    '"nsec":{"type":"integer","minimum":0,"maximum":999999999}}},"frame_id":{"type":"string"},"id":{"type'
    '":"string"},"lifetime":{"type":"object","title":"duration","properties":{"sec":{"type":"integer"},"n'
    'sec":{"type":"integer","minimum":0,"maximum":999999999}}},"frame_locked":{"type":"boolean"},"metadat'
    'a":{"type":"array","items":{"title":"foxglove.KeyValuePair","type":"object","properties":{"key":{"ty'
    'pe":"string"},"value":{"type":"string"}},"required":["key","value"]}},"arrows":{"type":"array","item'
    's":{"title":"foxglove.ArrowPrimitive","type":"object","properties":{"pose":{"title":"foxglove.Pose",'
    '"type":"object","properties":{"position":{"title":"foxglove.Vector3","type":"object","properties":{"'
    'x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"orienta'
    'tion":{"title":"foxglove.Quaternion","type":"object","properties":{"x":{"type":"number"},"y":{"type"'
    ':"number"},"z":{"type":"number"},"w":{"type":"number"}},"required":["x","y","z","w"]}},"required":["'
    'position","orientation"]},"shaft_length":{"type":"number"},"shaft_diameter":{"type":"number"},"head_'
    'length":{"type":"number"},"head_diameter":{"type":"number"},"color":{"title":"foxglove.Color","type"'
    ':"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type'
    '":"number"}},"required":["r","g","b","a"]}},"required":["pose","shaft_length","shaft_diameter","head'
    '_length","head_diameter","color"]}},"cubes":{"type":"array","items":{"title":"foxglove.CubePrimitive'
    '","type":"object","properties":{"pose":{"title":"foxglove.Pose","type":"object","properties":{"posit'
    'ion":{"title":"foxglove.Vector3","type":"object","properties":{"x":{"type":"number"},"y":{"type":"nu'
    'mber"},"z":{"type":"number"}},"required":["x","y","z"]},"orientation":{"title":"foxglove.Quaternion"'
    ',"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w"'
    ':{"type":"number"}},"required":["x","y","z","w"]}},"required":["position","orientation"]},"size":{"t'
    'itle":"foxglove.Vector3","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"'
    'z":{"type":"number"}},"required":["x","y","z"]},"color":{"title":"foxglove.Color","type":"object","p'
    'roperties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type":"number"}}'
    ',"required":["r","g","b","a"]}},"required":["pose","size","color"]}},"spheres":{"type":"array","item'
    's":{"title":"foxglove.SpherePrimitive","type":"object","properties":{"pose":{"title":"foxglove.Pose"'
    ',"type":"object","properties":{"position":{"title":"foxglove.Vector3","type":"object","properties":{'
    '"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"orient'
    'ation":{"title":"foxglove.Quaternion","type":"object","properties":{"x":{"type":"number"},"y":{"type'
    '":"number"},"z":{"type":"number"},"w":{"type":"number"}},"required":["x","y","z","w"]}},"required":['
    '"position","orientation"]},"size":{"title":"foxglove.Vector3","type":"object","properties":{"x":{"ty'
    'pe":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"color":{"title'
    '":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"t'
    'ype":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]}},"required":["pose","size","colo'
    'r"]}},"cylinders":{"type":"array","items":{"title":"foxglove.CylinderPrimitive","type":"object","pro'
    'perties":{"pose":{"title":"foxglove.Pose","type":"object","properties":{"position":{"title":"foxglov'
    'e.Vector3","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"nu'
    'mber"}},"required":["x","y","z"]},"orientation":{"title":"foxglove.Quaternion","type":"object","prop'
    'erties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}},"r'
    'equired":["x","y","z","w"]}},"required":["position","orientation"]},"size":{"title":"foxglove.Vector'
    '3","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}},'
    '"required":["x","y","z"]},"bottom_scale":{"type":"number"},"top_scale":{"type":"number"},"color":{"t'
    'itle":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b"'
    ':{"type":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]}},"required":["pose","size","'
    'bottom_scale","top_scale","color"]}},"lines":{"type":"array","items":{"title":"foxglove.LinePrimitiv'
    'e","type":"object","properties":{"type":{"title":"foxglove.LineType","oneOf":[{"title":"LINE_STRIP",'
    '"const":0},{"title":"LINE_LOOP","const":1},{"title":"LINE_LIST","const":2}]},"pose":{"title":"foxglo'
    've.Pose","type":"object","properties":{"position":{"title":"foxglove.Vector3","type":"object","prope'
    'rties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]}'
    ',"orientation":{"title":"foxglove.Quaternion","type":"object","properties":{"x":{"type":"number"},"y'
    '":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}},"required":["x","y","z","w"]}},"req'
    'uired":["position","orientation"]},"thickness":{"type":"number"},"scale_invariant":{"type":"boolean"'
    '},"points":{"type":"array","items":{"title":"foxglove.Point3","type":"object","properties":{"x":{"ty'
    'pe":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]}},"color":{"titl'
    'e":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"'
    'type":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]},"colors":{"type":"array","items'
    '":{"title":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"'
    '},"b":{"type":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]}},"indices":{"type":"arr'
    'ay","items":{"type":"integer","minimum":0}}},"required":["type","pose","thickness","scale_invariant"'
    ',"points","color","colors","indices"]}},"triangles":{"type":"array","items":{"title":"foxglove.Trian'
    'gleListPrimitive","type":"object","properties":{"pose":{"title":"foxglove.Pose","type":"object","pro'
    'perties":{"position":{"title":"foxglove.Vector3","type":"object","properties":{"x":{"type":"number"}'
    ',"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"orientation":{"title":"foxg'
    'love.Quaternion","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"typ'
    'e":"number"},"w":{"type":"number"}},"required":["x","y","z","w"]}},"required":["position","orientati'
    'on"]},"points":{"type":"array","items":{"title":"foxglove.Point3","type":"object","properties":{"x":'
    '{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]}},"color":{"'
    'title":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b'
    '":{"type":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]},"colors":{"type":"array","i'
    'tems":{"title":"foxglove.Color","type":"object","properties":{"r":{"type":"number"},"g":{"type":"num'
    'ber"},"b":{"type":"number"},"a":{"type":"number"}},"required":["r","g","b","a"]}},"indices":{"type":'
    '"array","items":{"type":"integer","minimum":0}}},"required":["pose","points","color","colors","indic'
    'es"]}},"texts":{"type":"array","items":{"title":"foxglove.TextPrimitive","type":"object","properties'
    '":{"pose":{"title":"foxglove.Pose","type":"object","properties":{"position":{"title":"foxglove.Vecto'
    'r3","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}'
    ',"required":["x","y","z"]},"orientation":{"title":"foxglove.Quaternion","type":"object","properties"'
    ':{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}},"required'
    '":["x","y","z","w"]}},"required":["position","orientation"]},"billboard":{"type":"boolean"},"font_si'
    'ze":{"type":"number"},"scale_invariant":{"type":"boolean"},"color":{"title":"foxglove.Color","type":'
    '"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type"'
    ':"number"}},"required":["r","g","b","a"]},"text":{"type":"string"}},"required":["pose","billboard","'
    'font_size","scale_invariant","color","text"]}},"models":{"type":"array","items":{"title":"foxglove.M'
    'odelPrimitive","type":"object","properties":{"pose":{"title":"foxglove.Pose","type":"object","proper'
    'ties":{"position":{"title":"foxglove.Vector3","type":"object","properties":{"x":{"type":"number"},"y'
    '":{"type":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"orientation":{"title":"foxglov'
    'e.Quaternion","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":'
    '"number"},"w":{"type":"number"}},"required":["x","y","z","w"]}},"required":["position","orientation"'
    ']},"scale":{"title":"foxglove.Vector3","type":"object","properties":{"x":{"type":"number"},"y":{"typ'
    'e":"number"},"z":{"type":"number"}},"required":["x","y","z"]},"color":{"title":"foxglove.Color","typ'
    'e":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"ty'
    'pe":"number"}},"required":["r","g","b","a"]},"override_color":{"type":"boolean"},"url":{"type":"stri'
    'ng"},"media_type":{"type":"string"},"data":{"type":"string","contentEncoding":"base64"}},"required":'
    '["pose","scale","color","override_color","url","media_type","data"]}}},"required":["timestamp","fram'
    'e_id","id","lifetime","frame_locked","metadata","arrows","cubes","spheres","cylinders","lines","tria'
    'ngles","texts","models"]}}},"required":["deletions","entities"]}'
)

SCENE_UPDATE_SCHEMA: dict[str, Any] = json.loads(_SCENE_UPDATE_SCHEMA_TEXT)
SCENE_UPDATE_SCHEMA_BYTES = _SCENE_UPDATE_SCHEMA_TEXT.encode()

_IDENTITY_JSON = '{"x":0.0,"y":0.0,"z":0.0,"w":1.0}'
_RING = [(math.cos(2 * math.pi * i / RING_POINTS), math.sin(2 * math.pi * i / RING_POINTS)) for i in range(RING_POINTS)]

# Scenes are written straight as JSON text from these fragments (no dicts, no json.dumps):
# the recorder derives two full-swarm scenes per step, and this keeps that cheap
# (docs/recording.md, ``swarm bench record``). Floats use ``repr``, as ``json`` does.


def _num(value: float) -> str:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"non-finite coordinate {value!r} in a scene")
    return repr(v)


def stamp(ns: int) -> str:
    """A ``time`` ({sec, nsec}) from nanoseconds since the epoch (negative times clamp to 0)."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return f'{{"sec":{max(sec, 0)},"nsec":{nsec if sec >= 0 else 0}}}'


def _pose(x: str, y: str, z: str = "0.0") -> str:
    return f'{{"position":{{"x":{x},"y":{y},"z":{z}}},"orientation":{_IDENTITY_JSON}}}'


def sphere(x: str, y: str, diameter: float, color: str) -> str:
    """A ``foxglove.SpherePrimitive`` at (x, y) (JSON numbers as text, from ``_num``), metres."""
    d = _num(diameter)
    return f'{{"pose":{_pose(x, y)},"size":{{"x":{d},"y":{d},"z":{d}}},"color":{color}}}'


def disc(x: str, y: str, radius: float, color: str) -> str:
    """A flat ``foxglove.CylinderPrimitive`` of ``radius`` (m) centred on (x, y): a robot's body."""
    d, h = _num(2.0 * radius), _num(DISC_HEIGHT_M)
    return (f'{{"pose":{_pose(x, y)},"size":{{"x":{d},"y":{d},"z":{h}}},"bottom_scale":1.0,"top_scale":1.0,'
            f'"color":{color}}}')


def label(x: str, y: str, text: int | str, color: str = WHITE) -> str:
    """A billboard ``foxglove.TextPrimitive`` showing ``text`` (an id, or ids joined by ``-``) just above (x, y)."""
    return (f'{{"pose":{_pose(x, y, _num(LABEL_DZ_M))},"billboard":true,"font_size":{_num(LABEL_PX)},'
            f'"scale_invariant":true,"color":{color},"text":"{text if isinstance(text, str) else int(text)}"}}')


@functools.lru_cache(maxsize=8)
def _ring_points(radius: float) -> str:
    return "[" + ",".join(f'{{"x":{_num(radius * c)},"y":{_num(radius * s)},"z":0.0}}' for c, s in _RING) + "]"


def ring(x: str, y: str, radius: float, color: str) -> str:
    """A closed circle (``foxglove.LinePrimitive`` of type LINE_LOOP = 1) of ``radius`` (m) around (x, y)."""
    return (f'{{"type":1,"pose":{_pose(x, y)},"thickness":{_num(RING_THICKNESS_M)},"scale_invariant":false,'
            f'"points":{_ring_points(radius)},"color":{color},"colors":[],"indices":[]}}')


def entity(entity_id: str, stamp_json: str, *, spheres: str = "", texts: str = "", lines: str = "", cylinders: str = "",
           metadata: Mapping[str, Any] | None = None) -> str:
    """A ``foxglove.SceneEntity`` in frame ``world``: every field the schema requires, unused primitives empty.

    ``spheres``/``texts``/``lines``: comma-joined primitives (JSON text); ``entity_id`` and the
    metadata keys and values must need no JSON escaping (ours are ids and numbers).
    """
    meta = ",".join(f'{{"key":"{k}","value":"{v}"}}' for k, v in (metadata or {}).items())
    return (f'{{"timestamp":{stamp_json},"frame_id":"{FRAME}","id":"{entity_id}","lifetime":{{"sec":0,"nsec":0}},'
            f'"frame_locked":false,"metadata":[{meta}],"arrows":[],"cubes":[],"spheres":[{spheres}],'
            f'"cylinders":[{cylinders}],"lines":[{lines}],"triangles":[],"texts":[{texts}],"models":[]}}')


def scene_update(entities: Iterable[str]) -> bytes:
    """The UTF-8 JSON of a ``foxglove.SceneUpdate`` with these entities and no deletions."""
    return ('{"deletions":[],"entities":[' + ",".join(entities) + "]}").encode()


def moving_robots(plan: PlanMessage | None, step: int) -> frozenset[int] | None:
    """The group of ``plan`` that moves at global step ``step``, or None when the plan does not cover it."""
    if plan is None:
        return None
    k = step - plan.step
    if 0 <= k < len(plan.groups):
        return frozenset(plan.groups[k])
    return None


def estimated_scene(msg: EstimateMessage, plan: PlanMessage | None = None) -> bytes:
    """Green spheres and id labels at the estimated positions; anchors of ``msg.step`` dark green with a ring."""
    moving = moving_robots(plan, msg.step)
    t = stamp(msg.stamp_ns)
    entities = []
    for robot, pose in zip(msg.ids, msg.poses, strict=True):
        x, y = _num(pose[0]), _num(pose[1])
        anchor = moving is not None and robot not in moving
        entities.append(entity(
            f"estimated/{int(robot)}", t,
            spheres=sphere(x, y, ANCHOR_SPHERE_M if anchor else SPHERE_M, DARK_GREEN if anchor else GREEN),
            texts=label(x, y, robot),
            lines=ring(x, y, RING_RADIUS_M, DARK_GREEN) if anchor else "",
            metadata={"robot": int(robot), "step": int(msg.step),
                      "anchor": "true" if anchor else "false" if moving is not None else "unknown"},
        ))
    return scene_update(entities)


def lost_scene(robot: int, x: float, y: float, stamp_ns: int) -> bytes:
    """A grey sphere labelled "<id> lost" at the robot's last estimated position (replaces its estimated entity)."""
    xs, ys = _num(x), _num(y)
    text = (f'{{"pose":{_pose(xs, ys, _num(LABEL_DZ_M))},"billboard":true,"font_size":{_num(LABEL_PX)},'
            f'"scale_invariant":true,"color":{GREY},"text":"{int(robot)} lost"}}')
    return scene_update([entity(f"estimated/{int(robot)}", stamp(stamp_ns), spheres=sphere(xs, ys, SPHERE_M, GREY), texts=text,
                                metadata={"robot": int(robot), "lost": "true"})])


def true_scene(poses: Mapping[int, Any], step: int, stamp_ns: int, radius: float = 0.0) -> bytes:
    """One blue sphere per robot at its true position ``poses[robot] = (x, y, heading)`` (replaces the previous ones);
    with bodies (``radius`` > 0, m) a blue disc of that radius instead."""
    t = stamp(stamp_ns)
    if radius > 0:
        return scene_update(
            entity(f"true/{int(robot)}", t, cylinders=disc(_num(pose[0]), _num(pose[1]), radius, BLUE),
                   metadata={"robot": int(robot), "step": int(step)})
            for robot, pose in sorted(poses.items())
        )
    return scene_update(
        entity(f"true/{int(robot)}", t, spheres=sphere(_num(pose[0]), _num(pose[1]), TRUE_SPHERE_M, BLUE),
               metadata={"robot": int(robot), "step": int(step)})
        for robot, pose in sorted(poses.items())
    )


def contact_scene(msg: ContactMessage) -> bytes:
    """A red ring of the body radius midway between the two robots at their closest, labelled ``a-b``."""
    x, y = _num(msg.point[0]), _num(msg.point[1])
    return scene_update([entity(
        f"contact/{int(msg.step)}/{int(msg.a)}-{int(msg.b)}", stamp(msg.stamp_ns),
        lines=ring(x, y, max(msg.radius_m, RING_THICKNESS_M), RED), texts=label(x, y, f"{int(msg.a)}-{int(msg.b)}", RED),
        metadata={"step": int(msg.step), "config": int(msg.config), "robots": f"{int(msg.a)}-{int(msg.b)}",
                  "distance_m": repr(float(msg.distance_m))},
    )])


def desired_scene(config: int, positions: Mapping[int, tuple[float, float]], stamp_ns: int,
                  legend_at: tuple[float, float] | None = None) -> bytes:
    """Red spheres and id labels at the desired positions of configuration ``config`` (1-based);
    with ``legend_at`` (x, y in m) also the ``legend`` entity there."""
    t = stamp(stamp_ns)
    entities = []
    for robot, (x, y) in positions.items():
        xs, ys = _num(x), _num(y)
        entities.append(entity(f"desired/{int(robot)}", t, spheres=sphere(xs, ys, SPHERE_M, RED), texts=label(xs, ys, robot, RED),
                               metadata={"robot": int(robot), "config": int(config)}))
    if legend_at is not None:
        entities.append(legend_entity(*legend_at, t))
    return scene_update(entities)


LEGEND = (  # (sphere colour, diameter m, ringed, text): every marker the scenes draw
    (RED, SPHERE_M, False, "desired: the configuration being planned"),
    (GREEN, SPHERE_M, False, "estimated (moves this step)"),
    (DARK_GREEN, ANCHOR_SPHERE_M, True, "anchor: stands still this step"),
    (BLUE, TRUE_SPHERE_M, False, "true (simulation or motion capture)"),
    (GREY, SPHERE_M, False, "lost robot (last estimate)"),
)
LEGEND_ROW_M = 0.08
LEGEND_TEXT_DX_M = 0.06  # from a sample's centre to its text's left edge
LEGEND_FONT_M = 0.035  # text height in metres (not scale invariant, so the column stays aligned when zooming)
CHAR_WIDTH = 0.6  # of the font size, for centring a line of text at a known left edge


def text(x: float, y: float, words: str, color: str = WHITE) -> str:
    """A billboard ``foxglove.TextPrimitive`` of ``words`` (``LEGEND_FONT_M`` high) whose left edge is near (x, y) m."""
    centre = _num(x + 0.5 * CHAR_WIDTH * LEGEND_FONT_M * len(words))  # Foxglove centres a text on its pose
    return (f'{{"pose":{_pose(centre, _num(y))},"billboard":true,"font_size":{_num(LEGEND_FONT_M)},'
            f'"scale_invariant":false,"color":{color},"text":{json.dumps(words)}}}')


def legend_entity(x: float, y: float, stamp_json: str) -> str:
    """The entity ``legend``: a sample of every marker of ``LEGEND`` in a column whose top-left is (x, y) m."""
    spheres, texts, lines = [], [], []
    for k, (col, diameter, ringed, words) in enumerate(LEGEND):
        xs, ys = _num(x), _num(y - k * LEGEND_ROW_M)
        spheres.append(sphere(xs, ys, diameter, col))
        if ringed:
            lines.append(ring(xs, ys, RING_RADIUS_M, col))
        texts.append(text(x + LEGEND_TEXT_DX_M, y - k * LEGEND_ROW_M, words))
    return entity("legend", stamp_json, spheres=",".join(spheres), texts=",".join(texts), lines=",".join(lines))


def legend_corner(configurations: list[dict[int, tuple[float, float]]]) -> tuple[float, float]:
    """Where the legend goes: above the top-left corner of every desired position (m)."""
    xy = [p for config in configurations for p in config.values()]
    return min(p[0] for p in xy), max(p[1] for p in xy) + 2 * LEGEND_ROW_M + (len(LEGEND) - 1) * LEGEND_ROW_M


def trajectory_configurations(trajectory: Any) -> list[dict[int, tuple[float, float]]] | None:
    """Per configuration (C_d1 first), robot -> desired (x, y), from a trajectory JSON object; None if unusable.

    Lenient on purpose (the recorder must never fail on metadata): anything that is not a
    trajectory object with matching lengths and finite numbers gives None.
    """
    if not isinstance(trajectory, Mapping):
        return None
    robots, configs = trajectory.get("robots"), trajectory.get("configurations")
    if not isinstance(robots, list) or not isinstance(configs, list):
        return None
    out = []
    try:
        ids = [int(r) for r in robots]
        for config in configs:
            if len(config) != len(ids):
                return None
            rows = {}
            for robot, xy in zip(ids, config, strict=True):
                x, y = float(xy[0]), float(xy[1])
                if not (math.isfinite(x) and math.isfinite(y)):
                    return None
                rows[robot] = (x, y)
            out.append(rows)
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return out


def metadata_radius(metadata: Mapping[str, Any] | None) -> float:
    """The body radius (m) in a run's metadata (``model.robot_radius_m``); 0 where absent or unusable (lenient)."""
    model = (metadata or {}).get("model")
    try:
        radius = float(model.get("robot_radius_m", 0.0)) if isinstance(model, Mapping) else 0.0
    except (TypeError, ValueError):
        return 0.0
    return radius if math.isfinite(radius) and radius > 0 else 0.0


class SceneDeriver:
    """Turns raw messages into ``(topic, SceneUpdate JSON bytes)`` pairs; keeps the trajectory and the latest plan.

    Not thread-safe: call from one thread (the recorder's writer thread) or under a lock.
    """

    def __init__(self, trajectory: Any = None, robot_radius: float = 0.0) -> None:
        self.configurations = trajectory_configurations(trajectory)
        self.radius = float(robot_radius)  # m: true robots drawn as discs of this radius (0: spheres)
        self.plan: PlanMessage | None = None
        self.truths: dict[int, TruthMessage] = {}
        self.truth_sets = False  # True once a TruthSetMessage was seen: it then draws the true scene
        self.last_estimate: dict[int, tuple[float, float]] = {}  # where a robot was last estimated (marks a lost robot)

    def derive(self, msg: Message) -> list[tuple[str, bytes]]:
        if isinstance(msg, EstimateMessage):
            self.last_estimate.update((int(r), (p[0], p[1])) for r, p in zip(msg.ids, msg.poses, strict=True))
            scenes = [(TOPIC_ESTIMATED, estimated_scene(msg, self.plan))]
            if self.truths and not self.truth_sets:
                poses = {robot: t.pose for robot, t in self.truths.items()}
                scenes.append((TOPIC_TRUE, true_scene(poses, msg.step, msg.stamp_ns, self.radius)))
            return scenes
        if isinstance(msg, TruthSetMessage):
            self.truth_sets = True
            return [(TOPIC_TRUE, true_scene(dict(zip(msg.ids, msg.poses, strict=True)), msg.step, msg.stamp_ns, self.radius))]
        if isinstance(msg, ContactMessage):
            return [(TOPIC_CONTACTS, contact_scene(msg))]
        if isinstance(msg, TruthMessage):
            self.truths[msg.robot] = msg
            return []
        if isinstance(msg, RobotEvent):
            where = self.last_estimate.get(msg.robot)
            if msg.kind == "lost" and where is not None:
                return [(TOPIC_ESTIMATED, lost_scene(msg.robot, where[0], where[1], msg.stamp_ns))]
            return []
        if isinstance(msg, PlanMessage):
            self.plan = msg
            if self.configurations is not None and 1 <= msg.config <= len(self.configurations):
                return [(TOPIC_DESIRED, desired_scene(msg.config, self.configurations[msg.config - 1], msg.stamp_ns,
                                                      legend_corner(self.configurations)))]
        return []


DERIVED_TYPES = (EstimateMessage, TruthSetMessage, PlanMessage, RobotEvent, ContactMessage)
"""Message types the recorder decodes for ``SceneDeriver.derive`` (single truths are only peeked there)."""


_JSON_TYPES: dict[str, tuple[type, ...]] = {"object": (dict,), "array": (list,), "string": (str,), "boolean": (bool,),
                                            "number": (int, float), "integer": (int,)}


def schema_errors(value: Any, schema: Mapping[str, Any] = SCENE_UPDATE_SCHEMA, path: str = "$", *,
                  strict: bool = True) -> list[str]:
    """What in ``value`` breaks ``schema`` (the subset of JSON Schema the Foxglove schemas use), [] if nothing.

    Checks type, required, properties, items, minimum/maximum and oneOf-const enums; with
    ``strict``, properties the schema does not define are errors too (catches typos).
    """
    errors: list[str] = []
    kind = schema.get("type")
    if kind is not None:
        ok = isinstance(value, _JSON_TYPES[kind]) and not (kind in ("number", "integer") and isinstance(value, bool))
        if not ok:
            return [f"{path}: {type(value).__name__} where {kind} is required"]
    if "oneOf" in schema:
        consts = [c.get("const") for c in schema["oneOf"]]
        if value not in consts or isinstance(value, bool):
            errors.append(f"{path}: {value!r} is not one of {consts}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            errors.append(f"{path}: {value!r} is not finite")
        if "minimum" in schema and value < schema["minimum"]:
            errors.append(f"{path}: {value!r} < {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            errors.append(f"{path}: {value!r} > {schema['maximum']}")
    if isinstance(value, dict):
        props = schema.get("properties", {})
        errors += [f"{path}: missing {name!r}" for name in schema.get("required", ()) if name not in value]
        for name, v in value.items():
            if name in props:
                errors += schema_errors(v, props[name], f"{path}.{name}", strict=strict)
            elif strict and props:
                errors.append(f"{path}: {name!r} is not in the schema")
    if isinstance(value, list) and "items" in schema:
        for i, v in enumerate(value):
            errors += schema_errors(v, schema["items"], f"{path}[{i}]", strict=strict)
    return errors


def entity_ids(scene: Mapping[str, Any]) -> Iterable[str]:
    """The entity ids of a scene (for tests and tools)."""
    return [e["id"] for e in scene.get("entities", ())]
