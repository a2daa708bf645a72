"""The observed skeleton of an image sequence (seed 003, Webb, II and III A; docs/design.md,
section 8): a tree of joints, one parent per joint, rooted at the reference joint whose depth
is known. Its edges are the rigid parts, numbered top-down (breadth first from the reference),
so a part comes after the parts above it. The default tree (`default_joint_tree`) is the
body's major joints with ``center_hip`` as the reference; the pelvis-to-C7 part stands for
the trunk.

Skeleton files (``diffbody webb --skeleton tree.json``) are JSON::

    {"format": "diffbody.joint_tree/1",
     "joints": [{"name": "center_hip", "parent": null},
                {"name": "left_hip", "parent": "center_hip"}, ...]}

Exactly one joint has ``"parent": null`` (the reference joint); names are unique; a parent
names another joint of the file; the joints' order is the image points' columns. A name that
is a joint or a feature of the body (``diffbody info --names``) lets the body give its
position (synthetic sequences, joint limits).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, rest_geometry, unknown_name_error
from ..files._skeleton_file import read_skeleton, write_skeleton

DEFAULT_JOINTS: tuple[tuple[str, str | None], ...] = (
    ("center_hip", None),
    ("left_hip", "center_hip"),
    ("left_knee", "left_hip"),
    ("left_ankle", "left_knee"),
    ("right_hip", "center_hip"),
    ("right_knee", "right_hip"),
    ("right_ankle", "right_knee"),
    ("C7_T1", "center_hip"),
    ("head.top", "C7_T1"),
    ("left_shoulder", "C7_T1"),
    ("left_elbow", "left_shoulder"),
    ("left_wrist", "left_elbow"),
    ("right_shoulder", "C7_T1"),
    ("right_elbow", "right_shoulder"),
    ("right_wrist", "right_elbow"),
)


class JointTree(eqx.Module):
    """A tree of observed joints (seed 003, Fig. 3). Static structure only: a compile-time
    constant of every kernel that takes it. Build it with `JointTree.from_parents`,
    `default_joint_tree` or `read_joint_tree`."""

    names: tuple[str, ...] = eqx.field(static=True)  # joints, in the image columns' order
    parents: tuple[int, ...] = eqx.field(static=True)  # joint index, -1 for the reference
    root: int = eqx.field(static=True)  # the reference joint
    part_start: tuple[int, ...] = eqx.field(static=True)  # joint, part k top-down
    part_end: tuple[int, ...] = eqx.field(static=True)  # joint
    part_parent: tuple[int, ...] = eqx.field(static=True)  # part above, -1 at the reference
    levels: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # parts by depth

    @staticmethod
    def from_parents(names, parents, where: str = "joint tree") -> "JointTree":
        """A tree from joint names and parent indices (-1 for the reference joint); refuses
        duplicates, no or several references, unknown parents and cycles, naming the joint."""
        names = tuple(str(n) for n in names)
        parents = tuple(int(p) for p in parents)
        n = len(names)
        if n < 2:
            raise ValueError(f"{where}: needs a reference joint and at least one more, got {n}")
        if len(parents) != n:
            raise ValueError(f"{where}: {n} names but {len(parents)} parents")
        seen: dict[str, int] = {}
        for i, name in enumerate(names):
            if not name:
                raise ValueError(f"{where}: joint {i} has an empty name")
            if name in seen:
                raise ValueError(
                    f"{where}: joint {name!r} is given twice (entries {seen[name]}, {i})"
                )
            seen[name] = i
        roots = [i for i, p in enumerate(parents) if p == -1]
        if len(roots) != 1:
            found = ", ".join(repr(names[i]) for i in roots) or "none"
            raise ValueError(
                f"{where}: exactly one joint must have no parent (the reference joint whose "
                f"depth is known), found {found}"
            )
        for i, p in enumerate(parents):
            if p != -1 and not 0 <= p < n:
                raise ValueError(f"{where}: joint {names[i]!r}: parent index {p} out of range")
            if p == i:
                raise ValueError(f"{where}: joint {names[i]!r} is its own parent")
        depth = [-1] * n
        for i in range(n):  # follow each joint up; a cycle never reaches the reference
            path, j = [], i
            while j != -1 and depth[j] < 0 and j not in path:
                path.append(j)
                j = parents[j]
            if j in path:
                cycle = " -> ".join(names[k] for k in path[path.index(j) :] + [j])
                raise ValueError(
                    f"{where}: the parents form a cycle ({cycle}); a skeleton is a tree: "
                    "every joint leads up to the reference joint"
                )
            base = -1 if j == -1 else depth[j]
            for k in reversed(path):
                base += 1
                depth[k] = base
        ends = sorted((i for i in range(n) if parents[i] != -1), key=lambda i: (depth[i], i))
        part_of = {e: k for k, e in enumerate(ends)}
        part_parent = tuple(part_of.get(parents[e], -1) for e in ends)
        levels: dict[int, list[int]] = {}
        for k, e in enumerate(ends):
            levels.setdefault(depth[e], []).append(k)
        return JointTree(
            names=names,
            parents=parents,
            root=roots[0],
            part_start=tuple(parents[e] for e in ends),
            part_end=tuple(ends),
            part_parent=part_parent,
            levels=tuple(tuple(levels[d]) for d in sorted(levels)),
        )

    @staticmethod
    def from_parent_names(joints, where: str = "joint tree") -> "JointTree":
        """A tree from (name, parent name or None) pairs."""
        joints = list(joints)
        names = [str(name) for name, _ in joints]
        index = {name: i for i, name in enumerate(names)}
        parents = []
        for name, parent in joints:
            if parent is None:
                parents.append(-1)
            elif parent not in index:
                raise unknown_name_error(
                    f"parent joint (of {name!r}, {where})", parent, tuple(names)
                )
            else:
                parents.append(index[parent])
        return JointTree.from_parents(names, parents, where)

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_parts(self) -> int:
        return len(self.part_end)

    @property
    def part_names(self) -> tuple[str, ...]:
        """ "start->end" of every part, top-down."""
        return tuple(
            f"{self.names[s]}->{self.names[e]}" for s, e in zip(self.part_start, self.part_end)
        )

    def index(self, name: str) -> int:
        """Index of a joint by name (KeyError listing the valid names)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise unknown_name_error("joint", name, self.names) from None

    def length_groups(self, symmetric: bool) -> tuple[int, ...]:
        """Per part, the index of its length among the distinct lengths: with `symmetric`,
        a part and its mirror image (names with "left" and "right" swapped) share one."""
        mirror = {"left": "right", "right": "left"}

        def swapped(name: str) -> str:
            for a, b in mirror.items():
                if a in name:
                    return name.replace(a, b)
            return name

        groups: dict[str, int] = {}
        out = []
        for s, e in zip(self.part_start, self.part_end):
            key = f"{self.names[s]}->{self.names[e]}"
            twin = f"{swapped(self.names[s])}->{swapped(self.names[e])}"
            if symmetric and twin in groups:
                out.append(groups[twin])
            else:
                groups[key] = len(groups)
                out.append(groups[key])
        return tuple(out)


def default_joint_tree() -> JointTree:
    """The body's major joints (see the module docstring): 15 joints, 14 rigid parts."""
    return JointTree.from_parent_names(DEFAULT_JOINTS, "default joint tree")


def read_joint_tree(path) -> JointTree:
    """A skeleton file (`diffbody.files.read_skeleton`); errors name the file, the entry and
    the field."""
    try:
        return JointTree.from_parent_names(read_skeleton(path), str(path))
    except KeyError as e:
        raise ValueError(e.args[0]) from None


def write_joint_tree(tree: JointTree, path) -> None:
    """Write a skeleton file that `read_joint_tree` reads back."""
    parents = [None if p == -1 else tree.names[p] for p in tree.parents]
    write_skeleton(list(zip(tree.names, parents)), path)


# --- the tree on a body ---------------------------------------------------------------------
def body_points(tree: JointTree, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Where each observed joint is on the body: (is_feature (J,) bool, index (J,)) into the
    body's joints or features (KeyError naming the joint when it is neither)."""
    is_feature, index = [], []
    for name in tree.names:
        if name in body.joint_names:
            is_feature.append(False)
            index.append(body.joint_names.index(name))
        elif name in body.feature_names:
            is_feature.append(True)
            index.append(body.feature_names.index(name))
        else:
            raise unknown_name_error(
                "body joint or feature", name, body.joint_names + body.feature_names
            )
    return np.asarray(is_feature), np.asarray(index)


def observed_points(
    tree: JointTree, body: Body, joint_positions: Array, feature_points: Array
) -> Float[Array, "n_obs 3"]:
    """The observed joints (J, 3) from a body's forward kinematics (`Kinematics`' joint
    positions and feature points)."""
    is_feature, index = body_points(tree, body)
    j = np.where(is_feature, 0, index)
    f = np.where(is_feature, index, 0)
    return jnp.where(is_feature[:, None], feature_points[f], joint_positions[j])


def hinge_limits(tree: JointTree, body: Body) -> tuple[tuple[int, int, float], ...]:
    """(part, part above, largest included angle in rad) for every part that is a hinge
    segment of the body (knee, elbow) hanging from the part that is its body parent, with
    both straight in the standard position: its flexion is then the angle between the two
    parts, which the body's hinge range bounds. Three points cannot tell flexion from
    hyperextension (the sign needs the twist), so only the range's extent is used."""
    out = []
    p_rest, _ = rest_geometry(body)
    for k, (s, e) in enumerate(zip(tree.part_start, tree.part_end)):
        above = tree.part_parent[k]
        if above < 0:
            continue
        names = (tree.names[tree.part_start[above]], tree.names[s], tree.names[e])
        if not all(n in body.joint_names for n in names):
            continue
        a, b, c = (body.joint_names.index(n) for n in names)
        segs = [i for i in range(body.n_segments) if body.distal_joint[i] == c]
        if not segs or body.proximal_joint[segs[0]] != b:
            continue
        seg = segs[0]
        parent = body.parent[seg]
        if body.limit_kind[seg] != "hinge" or body.proximal_joint[parent] != a:
            continue
        u, v = p_rest[b] - p_rest[a], p_rest[c] - p_rest[b]
        if np.dot(u, v) < np.cos(np.radians(1.0)) * np.linalg.norm(u) * np.linalg.norm(v):
            continue
        lo, hi = float(body.swing_lo[seg, 1]), float(body.swing_hi[seg, 1])
        out.append((k, above, max(abs(lo), abs(hi))))
    return tuple(out)
