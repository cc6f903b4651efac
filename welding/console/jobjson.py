"""Jobs as JSON for the browser, and back: the console edits a job as JSON, and every check
goes through the XML reader (:func:`welding.job.loads`), so the browser sees the same
problems, with line and column of the canonical XML, as ``welding job check``."""

from __future__ import annotations

from typing import Any

from welding import job as J

__all__ = ["JobJsonError", "job_from_json", "job_to_json", "problems_json"]

PATH_PARAMS = ("velocity", "laser", "power", "gas", "crossjet", "preflow", "postflow")
STITCH_PARAMS = ("duration", "power", "gas", "crossjet", "preflow", "postflow", "speed")


class JobJsonError(ValueError):
    """The JSON is not shaped like a job (a missing key, a wrong type)."""


def _loc_json(loc: J.Location) -> dict[str, Any]:
    return {"values": list(loc.values), "tool": loc.tool, "frame": loc.frame}


def _item_json(item: J.Item) -> dict[str, Any]:
    if isinstance(item, J.Pause):
        return {"kind": "pause", "name": item.name, "duration": item.duration}
    if isinstance(item, J.Via):
        return {"kind": "via", "name": item.name, "at": _loc_json(item.at), "speed": item.speed}
    if isinstance(item, J.Stitch):
        out = {"kind": "stitch", "name": item.name, "at": _loc_json(item.at)}
        return out | {k: getattr(item, k) for k in STITCH_PARAMS}
    segments = [
        {"kind": "line", "to": _loc_json(s.to)}
        if isinstance(s, J.Line)
        else {"kind": "arc", "mid": _loc_json(s.mid), "to": _loc_json(s.to)}
        for s in item.segments
    ]
    out = {"kind": "path", "name": item.name, "start": _loc_json(item.start)}
    return out | {"segments": segments} | {k: getattr(item, k) for k in PATH_PARAMS}


def job_to_json(job: J.Job) -> dict[str, Any]:
    return {
        "name": job.name,
        "description": job.description,
        "order": None if job.order is None else list(job.order),
        "items": [_item_json(i) for i in job.items],
    }


def _get(d: Any, key: str, kind: type | tuple[type, ...]) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise JobJsonError(f"missing {key!r}")
    v = d[key]
    if kind in (float, (float,)) and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, kind) or (kind is not bool and isinstance(v, bool)):
        raise JobJsonError(f"{key!r}: expected {getattr(kind, '__name__', kind)}, got {v!r}")
    return v


def _loc(d: Any, key: str) -> J.Location:
    loc = _get(d, key, dict)
    values = _get(loc, "values", list)
    if len(values) != 6:
        raise JobJsonError(f"{key!r}: expected 6 values")
    nums = [_get({"v": v}, "v", float) for v in values]
    x, y, z, rx, ry, rz = nums
    return J.Location(x, y, z, rx, ry, rz, _get(loc, "tool", str), _get(loc, "frame", str))


def _params(d: Any, names: tuple[str, ...]) -> dict[str, Any]:
    out = {}
    for k in names:
        out[k] = _get(d, k, bool if k in ("laser", "gas", "crossjet") else float)
    return out


def _item(d: Any) -> J.Item:
    kind, name = _get(d, "kind", str), _get(d, "name", str)
    if kind == "pause":
        return J.Pause(name, _get(d, "duration", float))
    if kind == "via":
        return J.Via(name, _loc(d, "at"), _get(d, "speed", float))
    if kind == "stitch":
        return J.Stitch(name, _loc(d, "at"), **_params(d, STITCH_PARAMS))
    if kind != "path":
        raise JobJsonError(f"unknown item kind {kind!r}")
    segments: list[J.Segment] = []
    for s in _get(d, "segments", list):
        if _get(s, "kind", str) == "arc":
            segments.append(J.Arc(_loc(s, "mid"), _loc(s, "to")))
        else:
            segments.append(J.Line(_loc(s, "to")))
    return J.Path(name, _loc(d, "start"), tuple(segments), **_params(d, PATH_PARAMS))


def job_from_json(d: Any) -> J.Job:
    """A :class:`~welding.job.Job` with whatever values the JSON has (checked afterwards by
    writing and reading it back); :class:`JobJsonError` when its shape is wrong."""
    order = d.get("order") if isinstance(d, dict) else None
    if order is not None and (
        not isinstance(order, list) or not all(isinstance(n, str) for n in order)
    ):
        raise JobJsonError("'order': expected a list of item names or null")
    description = d.get("description", "") if isinstance(d, dict) else ""
    if not isinstance(description, str):
        raise JobJsonError("'description': expected a string")
    items = tuple(_item(i) for i in _get(d, "items", list))
    return J.Job(_get(d, "name", str), items, None if order is None else tuple(order), description)


def problems_json(exc: J.JobError) -> list[dict[str, Any]]:
    return [
        {"line": p.line, "column": p.column, "message": p.text, "where": p.where, "field": p.field}
        for p in exc.problems
    ]
