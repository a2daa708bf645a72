"""Motion-capture markers on the walked body: the point kernel (`problem._points.tree_points`,
docs/design.md, sections 6 and 7) at the markers' offsets, each turned by its share of its
segment's twist at its own height."""

from jaxtyping import Array, Float

from ..problem._points import tree_points
from ..problem._problem import Problem
from ._marker_layout import MocapLayout


def tree_markers(
    lay: MocapLayout,
    problem: Problem,
    lengths: Float[Array, " n_seg"],
    offsets: Float[Array, "n 3"],
    x: Float[Array, " n_free"],
) -> Float[Array, "n 3"]:
    """World positions (m) of markers at `offsets` (their segments' cross of axes) on the
    problem's body with segment `lengths`, for the posture's free vector x: one walk, with
    closed-form derivatives in the posture, the lengths and the offsets."""
    return tree_points(lay.slots, problem, lengths, offsets, offsets[:, 2], x)


def model_markers(
    problem: Problem, lay: MocapLayout, offsets: Float[Array, "n 3"], x: Array
) -> Float[Array, "n 3"]:
    """`tree_markers` on the problem's own body."""
    return tree_markers(lay, problem, problem.body.lengths, offsets, x)
