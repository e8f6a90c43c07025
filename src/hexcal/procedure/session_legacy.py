"""Session files from older hexcal versions: what they may hold that the current schema does
not, and how it is read without losing anything.

An older hexcal saved a NaN or an infinity in a pose as ``null``. No valid pose record can hold
that, so on load such a pose is moved to ``set_aside`` whole (``unreadable_pose``), with a reason
naming the pose and the field; nothing else changes (docs/formats.md, "The session file").
"""

from __future__ import annotations

from typing import Any

#: The numbers of a pose an older hexcal may have saved as null (NaN, infinity): the table row's
#: and each raw sample's time. (A raw sample's own position, quaternion and readings may be null.)
_POSE_NUMBERS = ("t", "position", "quaternion", "readings")


def _null_fields(pose: dict[str, Any]) -> list[str]:
    """The fields of a saved pose that hold null where a number belongs."""
    found = []
    for key in _POSE_NUMBERS:
        if key not in pose:
            continue
        v = pose[key]
        if v is None:
            found.append(key)
        elif isinstance(v, list):
            found += [f"{key}.{j}" for j, x in enumerate(v) if x is None]
    for group in ("tracker_samples", "leg_samples"):
        samples = pose.get(group)
        if isinstance(samples, list):
            found += [
                f"{group}.{j}.t"
                for j, smp in enumerate(samples)
                if isinstance(smp, dict) and "t" in smp and smp["t"] is None
            ]
    return found


def _null_reason(pose: dict[str, Any], fields: list[str]) -> str:
    pid = pose.get("pose_id")
    name = f"pose {pid}" if isinstance(pid, int) else "a pose"
    listed = ", ".join(fields[:3]) + (f" and {len(fields) - 3} more" if len(fields) > 3 else "")
    verb = "was not a number" if len(fields) == 1 else "were not numbers"
    return f"{name}: {listed} {verb} (saved by an older hexcal); set aside on load"


def set_aside_null_poses(data: dict[str, Any]) -> list[str]:
    """Move every pose of a parsed session file that holds null where a number belongs (as an
    older hexcal saved NaN) to ``set_aside``, kept whole as ``unreadable_pose``; the same for a
    set-aside pose. The reasons, one per pose moved; everything else is left as it was."""
    reasons: list[str] = []
    poses, aside = data.get("poses"), data.get("set_aside", [])
    if not isinstance(aside, list):
        return reasons  # validation names the field
    if isinstance(poses, list):
        kept = []
        for p in poses:
            fields = _null_fields(p) if isinstance(p, dict) else []
            if not fields:
                kept.append(p)
                continue
            reason = _null_reason(p, fields)
            step = p.get("step") if isinstance(p.get("step"), str) else "?"
            aside.append({"step": step, "reason": reason, "unreadable_pose": p})
            reasons.append(reason)
        data["poses"] = kept
    for item in aside:
        pose = item.get("pose") if isinstance(item, dict) else None
        if not isinstance(pose, dict):
            continue
        fields = _null_fields(pose)
        if fields:
            reason = _null_reason(pose, fields)
            item["unreadable_pose"] = item.pop("pose")
            if isinstance(item.get("reason"), str):
                item["reason"] += f" — {reason}"
            reasons.append(reason)
    data["set_aside"] = aside
    return reasons
