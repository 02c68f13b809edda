"""Marker poses from ``/tf``: the chain of transforms from a parent frame down to the marker.

``--mocap-frame CHILD`` composes the chain from the root of CHILD's tree (the frame that has
no parent) down to CHILD; ``--mocap-frame PARENT:CHILD`` from PARENT (through their lowest
common ancestor when PARENT is not above CHILD). A mocap driver typically publishes
``mocap_origin -> drone`` on ``/tf`` and the room's placement ``world -> mocap_origin`` once on
``/tf_static``: the poses are then ``T_world_drone``.

A link whose value never changes (every ``/tf_static`` link, and a ``/tf`` link republished
unchanged) is applied as that constant. The poses are stamped by the moving link nearest the
marker; other moving links in the chain are interpolated at those stamps (position linearly,
rotation by slerp), never across one of their gaps and never extrapolated: poses outside are
left out, with a note.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.so3 import quat_multiply
from mocap_calib.core.policy import gap_threshold
from mocap_calib.errors import input_error
from mocap_calib.io.formats.ros.tf_wire import Transforms
from mocap_calib.io.validate import QUAT_NORM_TOL

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def frame(name: str) -> str:
    """Frame ids compare without a leading '/' (tf2 drops it; ROS 1 tf kept it)."""
    return name.lstrip("/")


def parse_frames(spec: str) -> tuple[str | None, str]:
    """``"world:drone"`` -> ``("world", "drone")``; ``"drone"`` -> ``(None, "drone")``."""
    parent, sep, child = spec.rpartition(":")
    return (frame(parent), frame(child)) if sep and parent else (None, frame(spec.lstrip(":")))


@dataclass(frozen=True)
class Link:
    """``T_parent_child`` over time: stamps (ns, sorted) and (K, 7) values (xyz, wxyz)."""

    parent: str
    child: str
    stamps: IntArray
    values: Array

    @property
    def constant(self) -> bool:
        return bool(np.all(self.values == self.values[0]))

    @property
    def name(self) -> str:
        return f"{self.parent} -> {self.child}"


def links(tf: Transforms, stamps: IntArray, static: Transforms | None, topic: str,
          source: str) -> dict[str, Link]:
    """Every child frame's link, from the TF topic's rows (stamped ``stamps``) and the static
    rows. A frame with two parents is an error naming them."""
    parts = [(tf, stamps)] + ([(static, static.stamp)] if static is not None else [])
    ids: dict[str, int] = {}
    parent, child, st, val = [], [], [], []
    for tr, stamp in parts:  # frame ids as normalised names' codes, shared by both topics
        code = np.array([ids.setdefault(frame(n), len(ids)) for n in tr.names] or [0])
        parent.append(code[tr.parent])
        child.append(code[tr.child])
        st.append(stamp)
        val.append(np.concatenate([tr.value[:, :3], tr.value[:, [6, 3, 4, 5]]], axis=1))
    names = list(ids)
    p_all, c_all, s_all, v_all = (np.concatenate(x) for x in (parent, child, st, val))
    out: dict[str, Link] = {}
    for c in np.unique(c_all).tolist():
        rows = np.flatnonzero(c_all == c)
        parents = sorted(names[i] for i in np.unique(p_all[rows]).tolist())
        if len(parents) > 1:
            raise input_error(f"frame '{names[c]}' has {len(parents)} parents on {topic} and "
                              f"/tf_static: {', '.join(parents)} (a TF tree gives each frame "
                              "one)", "record one TF tree, or pass the mocap's own pose topic "
                              "with --mocap-topic", source)
        order = rows[np.argsort(s_all[rows], kind="stable")]
        out[names[c]] = Link(parents[0], names[c], s_all[order], v_all[order])
    return out


def _up(child: str, tree: dict[str, Link]) -> list[str]:
    """``[child, parent, grandparent, ..., root]``."""
    path = [child]
    while path[-1] in tree:
        nxt = tree[path[-1]].parent
        if nxt in path:
            break  # a cycle: stop at the repeat (the chain is then named in any error)
        path.append(nxt)
    return path


def chain(tree: dict[str, Link], parent: str | None, child: str, topic: str, source: str
          ) -> tuple[list[Link], list[Link], str]:
    """Links from the common ancestor down to ``child`` and down to ``parent`` (empty when
    ``parent`` is above ``child``), and the parent frame's name."""
    up_c = _up(child, tree)
    if parent is None:
        parent = up_c[-1]
    up_p = _up(parent, tree)
    common = next((f for f in up_c if f in up_p), None)
    if common is None:
        frames = sorted(set(tree) | {lk.parent for lk in tree.values()})
        where = (" is in no transform" if parent not in frames else
                 f"'s chain ends at '{up_p[-1]}' ({' <- '.join(up_p)})")
        raise input_error(f"no TF chain links '{parent}' to '{child}' on {topic} and /tf_static: "
                          f"{child}'s chain ends at '{up_c[-1]}' ({' <- '.join(up_c)}), "
                          f"{parent}{where}", "record the missing transform (a static one on "
                          f"/tf_static), or pass --mocap-frame {up_c[-1]}:{child}", source)
    down_c = [tree[f] for f in reversed(up_c[:up_c.index(common)])]
    down_p = [tree[f] for f in reversed(up_p[:up_p.index(common)])]
    return down_c, down_p, parent


def _rotate(q: Array, v: Array) -> Array:
    """``R(q) v`` for unit ``[w, x, y, z]`` quaternions (rows)."""
    u = q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + q[:, :1] * t + np.cross(u, t)


def _slerp(q0: Array, q1: Array, s: Array) -> Array:
    dot = np.sum(q0 * q1, axis=1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
    small = theta < 1e-9
    sin = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - s, np.sin((1.0 - s) * theta) / sin)
    b = np.where(small, s, np.sin(s * theta) / sin)
    q = a[:, None] * q0 + b[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _at(link: Link, t: IntArray) -> tuple[Array, NDArray[np.bool_]]:
    """The link's values at stamps ``t`` (K, 7) and where they are known (no extrapolation,
    no interpolation across one of the link's gaps)."""
    if link.constant:
        return np.broadcast_to(link.values[0], (len(t), 7)), np.ones(len(t), bool)
    st, val = link.stamps, link.values
    j = np.clip(np.searchsorted(st, t, side="right"), 1, len(st) - 1)
    span = (st[j] - st[j - 1]).astype(float)
    ok = (t >= st[0]) & (t <= st[-1]) & (span * 1e-9 <= gap_threshold(st * 1e-9))
    s = np.where(span > 0, (t - st[j - 1]) / np.where(span > 0, span, 1.0), 0.0)
    p = val[j - 1, :3] + s[:, None] * (val[j, :3] - val[j - 1, :3])
    return np.concatenate([p, _slerp(val[j - 1, 3:], val[j, 3:], s)], axis=1), ok


def _unit(link: Link, source: str) -> Link:
    norm = np.linalg.norm(link.values[:, 3:], axis=1)
    bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if bad.any():
        raise input_error(f"the rotation of TF link {link.name} has norm {norm[bad][0]:.6g}, "
                          "not 1", "fix the node that publishes it", source)
    vals = link.values.copy()
    vals[:, 3:] /= norm[:, None]
    return Link(link.parent, link.child, link.stamps, vals)


def compose(down_c: list[Link], down_p: list[Link], source: str
            ) -> tuple[IntArray, Array, Array, list[str]]:
    """Stamps, quaternions ``wxyz`` and positions of ``T_parent_child``, and notes."""
    moving = [lk for lk in down_c + down_p if not lk.constant]
    if not moving:
        names = ", ".join(lk.name for lk in down_c + down_p)
        raise input_error(f"every TF link between the frames is constant ({names}): nothing "
                          "moves", "pass --mocap-frame naming the marker body's frame", source)
    near = [lk for lk in down_c if not lk.constant]
    base = near[-1] if near else moving[0]  # the moving link nearest the marker
    if len(down_c) == 1 and not down_p:  # one link: its values as recorded, bit for bit
        return base.stamps, base.values[:, 3:], base.values[:, :3], []
    t = base.stamps
    ok = np.ones(len(t), bool)
    notes: list[str] = []

    def pose(links_down: list[Link]) -> tuple[Array, Array]:
        nonlocal ok
        q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
        p = np.zeros((len(t), 3))
        for lk in links_down:
            v, known = _at(_unit(lk, source), t)
            if lk is not base and not lk.constant:
                notes.append(f"{source}: TF link {lk.name} interpolated at the {base.child} "
                             f"stamps ({int((~known & ok).sum())} poses outside it left out)")
            ok &= known
            p = p + _rotate(q, v[:, :3])
            q = quat_multiply(q, v[:, 3:])
        return q, p

    q_c, p_c = pose(down_c)
    q_p, p_p = pose(down_p)
    q_inv = q_p * np.array([1.0, -1.0, -1.0, -1.0])
    q = quat_multiply(q_inv, q_c)
    p = _rotate(q_inv, p_c - p_p)
    return t[ok], q[ok], p[ok], notes
