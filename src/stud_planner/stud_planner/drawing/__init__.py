"""The drawing: a stud layout read from a 2D DXF drawing -- stud circles plus the marks O, A, B.

Pure Python (ezdxf + numpy), no ROS: the drawing node converts :class:`DrawingLayout` to
``stud_welding_msgs/StudLayout`` (field for field; lengths are already metres).

Modules, one per concern, each with a public API (``__all__``):

* ``layout`` -- :func:`read_layout`, the one entry: it composes the concerns below into a
  :class:`DrawingLayout` (stud order, ids, duplicates, the warnings); ``options`` -- its frozen
  configuration :class:`LayoutOptions` (``with_changes``);
* ``dxf_file`` -- the file: checks (binary, truncated, not a DXF), ezdxf, recovery
  (:func:`open_drawing`); ``plain_circles`` -- the fast reader of an ASCII file's plain CIRCLE entities;
* ``entities`` -- entity collection: the dispatch table per DXF entity type and block expansion
  under the work budget (``limits``: :class:`DrawingLimits`); ``circles`` -- the usable circles of
  a drawing (:func:`read_circles`, a :class:`CircleSet`);
* ``visibility`` -- what CAD shows (invisible entities, frozen and off layers); ``layers`` -- the
  layer names and patterns a rule means;
* ``marks`` -- O, A, B and the reference marks M1, M2, ...; ``units`` and ``frame`` -- the drawing's
  unit and the drawing frame the marks define;
* ``neighbours`` -- the grid-hash neighbour search (duplicates, close pairs);
* ``layout_types`` -- the results and :class:`DrawingError`; ``dxf_writer`` -- drawings for tests,
  demos and benchmarks.

What is read
    * DXF R12 .. R2018 (and the pre-R12 files ezdxf accepts), ASCII or binary, via
      ``ezdxf.readfile``; a damaged file that only ``ezdxf.recover.readfile`` can read is
      used with a warning. A file that does not end in ``EOF`` (or a closed section) is
      *truncated* and refused: a partial entity list would silently drop studs.
    * Large drawings: the plain CIRCLE entities of an ASCII file's modelspace are read as
      arrays by :mod:`stud_planner.drawing.plain_circles` and ezdxf loads the rest of the file; the
      same rules apply to both and the result is identical (tested on the whole corpus), so a
      bridge's 250,000 studs take seconds, not ezdxf's minutes. ``read_circles(...,
      plain_circles=False)`` reads everything through ezdxf.
    * Modelspace only. INSERT (and MINSERT) block references are expanded recursively with
      their full transform (insertion point, block base point, rotation, non-uniform and
      negative scale, extrusion, nesting). Entities on layer ``0`` inside a block take the
      layer of the INSERT that places them (the DXF convention), so a ``STUD`` block drawn
      on layer 0 and inserted on ``STUDS`` yields studs on ``STUDS``.
    * ``Circle.dxf.center`` is in the entity's OCS: centres are taken to WCS with the
      arbitrary-axis algorithm, so circles with extrusion (0, 0, -1) (mirrored drawings)
      land where CAD shows them.

Decisions (each one is reported as a warning when it applies)
    * A circle that a block reference scales non-uniformly is an ellipse, not a stud
      circle: it is **skipped** (as ezdxf's own ``virtual_entities`` turns it into an ELLIPSE;
      taking its centre would hide a drawing error). Circles whose plane is not parallel to XY
      (tilted extrusion) are skipped likewise. Rounding-level differences (< 0.01 %) are not
      non-uniform.
    * ezdxf reports ``$INSUNITS`` 6 (metres) for a file without a HEADER section; such a file
      is treated as unitless, since it says nothing about its units.
    * Circles with radius <= 0 are skipped.
    * A circle with a non-finite (NaN, inf) or absurd coordinate or radius (beyond
      ``MAX_COORDINATE_M``, 1e8 m, in WCS -- 1e300 is not a position) is **left out with a
      warning naming its handle and layer** (``DrawingLayout.invalid_entities`` lists each one,
      ``plan`` repeats them as report warnings): it has no position to weld at. Left out rather
      than refused, like the other skips above, so that one broken entity of a 250,000-stud
      drawing does not stop the job; a mark left out is an error all the same (marks missing).
    * What CAD does not show is not part of the drawing: entities flagged invisible (group
      60) and entities on layers that are frozen or off are skipped (a frozen INSERT hides its
      whole block, an off one what inherits its layer), with a warning per layer;
      ``include_hidden_layers`` reads hidden layers all the same. An old revision's studs on a
      frozen ``STUDS_OLD`` must not be welded because a pattern ``STUDS*`` matches it.
    * A degenerate INSERT (zero scale, a transform that raises in ezdxf) is skipped; the rest
      of the drawing is kept.
    * Unitless drawings (``$INSUNITS`` 0 or absent) use ``units_if_unitless`` (default mm).
    * Block expansion has a work budget (:class:`DrawingLimits`: nesting depth, entities expanded,
      MINSERT cells, text size), counted before anything is expanded: a drawing that asks for more
      (ten nested levels of ten INSERTs each are 10^10 circles in 3 KB) is refused with
      :class:`DrawingLimitError`, one line naming the block, its level and the count. The defaults
      are far beyond real drawings; each can be raised.

Marks (``marks_rule``)
    * ``"labels"``: each circle on the mark layer takes the letter of its nearest TEXT /
      MTEXT / ATTRIB whose text is ``O``, ``A`` or ``B`` (case-insensitive), if that label is
      within ``label_distance_factor`` mark diameters of the circle's centre. Used when each
      letter names exactly one circle.
    * ``"geometry"``: otherwise, with exactly three mark circles: O is the vertex whose angle
      is closest to 90 deg; A and B are then chosen so that OA x OB > 0 (B counter-clockwise
      from A, a right-handed frame).
    Concentric mark circles (centres within ``duplicate_tol_m``) count as one mark (the
    largest circle), so a target symbol drawn as two rings is one mark.

Reference marks (``DrawingLayout.reference_marks``)
    A long part may carry reference marks beside O, A, B, painted along the part so that each
    camera station registers on the marks it sees: circles on the mark layer labelled ``M1``,
    ``M2``, ... by TEXT / MTEXT / ATTRIB as O, A, B are (``M01`` reads as ``M1``). They are read
    in label order (M1, M2, ..., M10), in the drawing frame (metres), and are never studs. In a
    drawing with reference marks every mark-layer circle must be labelled: an unlabelled one is
    an error naming where it is (a reference mark without its label would silently be left
    out), as is a label nearest to two circles; an ``M`` label next to no mark circle is warned
    about (``M16`` may be a thread size).

Drawing frame (INTERFACES.md, frame ``drawing``)
    Origin at O, x along OA, y perpendicular to x on B's side; metres. If the labels put B
    clockwise from A the frame is a reflection of the DXF's WCS (``mirrored=True``, warned:
    the drawing is probably seen from below); the coordinates are still "along OA" and
    "toward B". If angle AOB is not 90 deg (within ``perpendicular_tol_deg``) a warning
    gives the angle.

Stud order and ids
    Studs are sorted by (layer name, case-folded), then row (drawing y), then drawing x in the
    row, then diameter and the exact coordinates; a row holds the studs whose y differ by less
    than 0.1 mm (chained), and x within a row is compared the same way, so the float noise of a
    rotated or shifted placement never reorders studs. Ids are ``S0001``, ``S0002``,
    ... in that order (4 digits; all ids get 5 digits from 10 000 studs on, so that text order
    stays id order). The key depends only on the geometry, so ids do not change when a CAD
    program reorders entities in the file. Duplicates (centres within ``duplicate_tol_m``, any
    layer) keep the first stud in this order.

Warnings (``DrawingLayout.warnings``, one line each) and errors
    Warned: duplicates removed, stud pairs closer than ``min_spacing_m``, diameters far from
    the median, studs outside the marks' quadrant (x < 0 or y < 0), non-perpendicular or
    mirrored marks, assumed units, recovered files, and everything skipped above.
    Refused with :class:`DrawingError` (one line naming the file): missing file, not a DXF,
    truncated/corrupt file, no studs (listing the layers with entity and circle counts), marks
    missing or ambiguous (how many circles on which layer), collinear or coincident marks.
    The duplicate and spacing checks use a grid hash (:func:`close_pairs`), O(N) for sane
    spacing. Reading is linear in the number of studs (bench/RESULTS.md, *Offline planning at
    bridge scale*).
"""
from stud_planner.drawing.circles import collect_circles, read_circles
from stud_planner.drawing.dxf_file import load_document
from stud_planner.drawing.layout import read_layout
from stud_planner.drawing.layout_types import CircleSet, DrawingError, DrawingLayout, Mark, Stud
from stud_planner.drawing.limits import DrawingLimitError, DrawingLimits
from stud_planner.drawing.neighbours import close_pairs
from stud_planner.drawing.options import LayoutOptions
from stud_planner.drawing.units import UNITS, units_to_metres

__all__ = ["DrawingError", "DrawingLimitError", "DrawingLimits", "Stud", "Mark", "DrawingLayout", "CircleSet",
           "LayoutOptions", "read_layout", "read_circles", "collect_circles", "load_document", "close_pairs", "UNITS",
           "units_to_metres"]
