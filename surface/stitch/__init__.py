r"""Delaunay-stitched triangle mesh from closed section rings.

Between two adjacent sections, odd points :math:`o_k` at :math:`\theta = 2\pi k/N` and
even points :math:`e_j` at :math:`\theta = \pi j/N`, the *direction criterion* [2]_ builds

.. math::

    (o_k, e_{2k}, e_{2k+1}),\quad (o_k, e_{2k+1}, o_{k+1}),\quad
    (o_{k+1}, e_{2k+1}, e_{2k+2}),\qquad k = 0, \dots, N-1.

For any two ring sizes it is a merge by angle about one centre (:mod:`.tiling`): each
ring of :math:`n_a` and :math:`n_b` points gives :math:`n_a + n_b` triangles; a ring not
star-shaped about it is tiled by the shortest total span (Fuchs et al. 1977).  Lawson's
flips [1]_ (:math:`\angle acb + \angle adb > \pi`) then improve each strip and each cap
(:mod:`.flips`, a numba kernel), never across a section contour.  Splits and merges are
bridged (:mod:`.bridges`), ends and appearing loops capped (:mod:`.caps`).  All faces are
counter-clockwise seen from outside.

Support rings (:mod:`.support`): Loop's G1 surface passes a corner of turn α and legs h at
:math:`h\sin(\alpha/2)/3` from it; where the profile turns sharply and that exceeds the
noise σ̂, a ring is added on each leg at :math:`d = 3\hat\sigma/\sin(\alpha/2)`, so the
rounding falls to σ̂ (an exact crease rule [3]_ [4]_ was not taken).  The rules, their
figures and what each fixed: ``docs/method/stitching.md``.

References
----------
.. [1] C. L. Lawson, "Software for C1 surface interpolation", in Mathematical
   Software III, Academic Press (1977), 161-194.
.. [2] The paper's section-to-section direction criterion (DESIGN.md, "Stitching").
.. [3] H. Hoppe et al., "Piecewise smooth surface reconstruction", SIGGRAPH 1994,
   295-302.
.. [4] T. DeRose, M. Kass, T. Truong, "Subdivision surfaces in character
   animation", SIGGRAPH 1998, 85-94.
"""

from __future__ import annotations

from surface.polygon import inside_polygon as _inside  # noqa: F401 - as the module had it
from surface.stitch.bridges import (  # noqa: F401 - the package's names, as one module's
    BRIDGE_NEIGHBOURS,
    BRIDGE_ORDERS,
    SLIVER,
    _best_window,
    _bridge_heights,
    _bridge_split,
    _bridge_split_in,
)
from surface.stitch.caps import (  # noqa: F401 - the package's names, as one module's
    CAP_GUARD_RINGS,
    CAP_MIN_ANGLE,
    CAP_MIN_POINTS,
    CAP_SHRINK,
    CHI2_1_MEDIAN,
    COVER_RADIUS,
    DOME_MAX_NEIGHBOURS,
    DOME_NEIGHBOURS,
    DOME_RATIO,
    DOME_TEST_POINTS,
    DOME_WIDTH_TEST_POINTS,
    HOLE_SHARE,
    QUADRATIC_BATCH,
    SNAP_BITS,
    _cap_step,
    _closes,
    _dome,
    _dome_neighbours,
    _inset_ring,
    _local_quadratic,
    _quadratic_heights,
    _quality_cap,
    _scaled,
    _snapped,
    cap_triangles,
    end_window,
    uncovered_share,
)
from surface.stitch.checks import (  # noqa: F401 - the package's names, as one module's
    _edges_cross,
    loops_cross,
    self_intersects,
)
from surface.stitch.core import (  # noqa: F401 - the package's names, as one module's
    StitchResult,
    _as_sections,
    stitch_rings,
)
from surface.stitch.flips import (  # noqa: F401 - the package's names, as one module's
    EDGE_TABLE_LOAD,
    MAX_NORMAL_CHANGE,
    _angle_at,
    _edge_keys,
    _empty_table,
    _flippable_edges,
    _folds,
    _grown,
    _half_edges,
    _lawson,
    _normal_of,
    _slot,
    _turns_over,
    delaunay_flips,
)
from surface.stitch.support import (  # noqa: F401 - the package's names, as one module's
    FACING_SUPPORT_SHARE,
    SHARP_TURN,
    SUPPORT_MIN_SHARE,
    SUPPORT_SHARE,
    _nearest_loop,
    _read_at,
    _support,
    _support_ring,
    support_distance,
)
from surface.stitch.tiling import (  # noqa: F401 - the package's names, as one module's
    MIN_SPAN_STARTS,
    MIN_SPAN_TIE,
    _edge_sides,
    _min_span_from,
    _min_span_moves,
    _nested_angles,
    _ring_order_and_parameter,
    _star_shaped,
    axis_frame,
    tile_min_span,
    zip_rings,
)

__all__ = ["StitchResult", "stitch_rings", "zip_rings", "cap_triangles", "delaunay_flips",
           "axis_frame", "support_distance"]
