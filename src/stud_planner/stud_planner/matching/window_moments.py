"""Moment sums of inverse depth over block-aligned windows: one pass over the frame, then O(1) per window.

The least-squares quadric fit of 1/z over a window (:mod:`stud_planner.matching.surface_pose`) needs only sums
over the window's valid pixels: of u^p v^q (p + q <= 4), of y u^p v^q (p + q <= 2, y = 1/z) and of
y^2. Those sums are additive over any partition of the window, so the image is cut into square
blocks of :data:`BLOCK_PX` pixels and a window is made of whole blocks. Many windows get their sums
from summed-area tables of the block sums (each block's sums computed once, a few BLAS products
over the part of the frame the windows cover; then four look-ups per channel a window); few
windows from their own pixels (no table to build). Both give the same numbers up to rounding
(normals agree to 1e-4 deg, sigmas to 0.2 %); which one runs is a matter of cost only.

Coordinates: sums are accumulated in a frame-wide scaled coordinate (X, Y) = ((u, v) - image
centre) / :data:`COORD_SCALE_PX` (moments of order 4 of pixel coordinates would lose digits to
cancellation in float64 otherwise) and returned about each window's own centre, in pixels.
Inverse depth is taken relative to ``y_ref_per_m`` (1/m), a constant the caller adds back to the
fit's constant term, so the sum of y^2 keeps the residual's digits.

Pure numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

#: Side of a block (px). Windows are whole blocks: their edges move by at most half a block.
BLOCK_PX = 8
#: Pixels per unit of the frame-wide coordinate in which block sums are accumulated.
COORD_SCALE_PX = 64.0

#: The channels of a window's sums: (p, q) exponents of (u, v) for the weight (validity) moments
#: up to order 4, then for the inverse-depth moments up to order 2, then y^2.
W_TERMS = tuple((p, q) for d in range(5) for p in range(d, -1, -1) for q in (d - p,))
Y_TERMS = tuple((p, q) for d in range(3) for p in range(d, -1, -1) for q in (d - p,))
N_CHANNELS = len(W_TERMS) + len(Y_TERMS) + 1
#: No depth -- NaN, 0, negative or -inf -- becomes this depth (m) before 1/z: an inverse depth far
#: beyond :data:`_MAX_INVERSE_DEPTH` yet finite, so masking it out multiplies by 0 without making
#: a NaN (1/0 = inf, and inf * 0 is NaN). +inf ("too far", REP 118) gives 1/z = 0: no depth too.
_NO_DEPTH_M = np.float32(1e-30)
_MAX_INVERSE_DEPTH = np.float32(1e6)  # 1/m: a depth under 1 micrometre is no depth
#: Up to this fraction of blocks with a hole, their validity sums are taken pixel by pixel and
#: the whole blocks' in closed form; beyond it, one product over the whole image is cheaper.
_HOLED_BLOCKS_PIXELWISE = 0.3


@dataclass(frozen=True)
class WindowSums:
    """Sums over the valid pixels of n windows, about each window's centre, in pixels.

    ``mw`` (n, 5, 5) [p, q] = sum u'^p v'^q (entries with p + q > 4 are 0); ``my`` (n, 3, 3)
    [p, q] = sum y' u'^p v'^q (p + q <= 2); ``yy`` (n,) = sum y'^2; with u', v' the pixel offsets
    from the window's centre and y' = 1/z - y_ref (1/m). ``centre_uv`` (n, 2) px, ``n_window`` (n,)
    pixels of the window inside the image; ``step`` (px): the sums are over every ``step``-th pixel
    of each row and column (``n_window`` counts those), 1: every pixel.
    """

    mw: np.ndarray
    my: np.ndarray
    yy: np.ndarray
    centre_uv: np.ndarray
    n_window: np.ndarray
    step: int = 1


def powers_of(x: np.ndarray, order: int) -> np.ndarray:
    """x[..., None] ** (0..order), (..., order + 1)."""
    out = np.empty(np.shape(x) + (order + 1,))
    out[..., 0] = 1.0
    for k in range(1, order + 1):
        out[..., k] = out[..., k - 1] * x
    return out




def _reciprocal_depth(z: np.ndarray, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(1/z written to ``out``, valid) of depths ``z`` (m): every "no depth" -- NaN, 0, negative,
    -inf -- goes to :data:`_NO_DEPTH_M` first and +inf gives 0, so both fail the validity test and
    ``out`` stays finite where they are."""
    np.fmax(z, _NO_DEPTH_M, out=out)
    y = np.divide(np.float32(1.0), out, out=out)
    return y, (y > 0) & (y < _MAX_INVERSE_DEPTH)


def _binomial_shift(d: np.ndarray, order: int = 4) -> np.ndarray:
    """(n, order + 1, order + 1) matrices B with B[p, r] = C(p, r) (-d)^(p - r): the moments
    sum (x - d)^p of a set of points from its moments sum x^r, as B @ moments."""
    pw = powers_of(-np.asarray(d, dtype=np.float64), order)
    B = np.zeros(np.shape(d) + (order + 1, order + 1))
    for p in range(order + 1):
        for r in range(p + 1):
            B[..., p, r] = comb(p, r) * pw[..., p - r]
    return B


def _shift(ch: dict, x0: np.ndarray, y0: np.ndarray, terms, order: int) -> dict:
    """Moments about (x0, y0) from moments about the origin: sum (x - x0)^p (y - y0)^q, for the
    (p, q) in ``terms``; ``ch`` maps (p, q) -> (n,) arrays. Binomial expansion, u then v."""
    px, py = [np.ones_like(x0)], [np.ones_like(y0)]  # powers of -x0, -y0, each contiguous
    for _ in range(order):
        px.append(px[-1] * -x0)
        py.append(py[-1] * -y0)
    half = {}
    for p, q in terms:  # sum (x - x0)^p y^q
        acc = ch[p, q].copy()
        for r in range(p):
            acc += comb(p, r) * px[p - r] * ch[r, q]
        half[p, q] = acc
    out = {}
    for p, q in terms:
        acc = half[p, q].copy()
        for s in range(q):
            acc += comb(q, s) * py[q - s] * half[p, s]
        out[p, q] = acc
    return out


class BlockMoments:
    """Per-block sums of one depth image, computed on demand (a set of blocks, or all of them).

    ``depth_m`` (H, W) metres, NaN, <= 0 or +-inf = no depth; ``y_ref_per_m`` the inverse depth the
    sums are taken relative to.
    """

    def __init__(self, depth_m: np.ndarray, y_ref_per_m: float) -> None:
        depth = np.asarray(depth_m)
        H, W = depth.shape
        b = BLOCK_PX
        self.n_rows, self.n_cols = -(-H // b), -(-W // b)
        if (H, W) != (self.n_rows * b, self.n_cols * b):  # pad with "no depth" to whole blocks
            padded = np.full((self.n_rows * b, self.n_cols * b), np.nan, dtype=depth.dtype)
            padded[:H, :W] = depth
            depth = padded
        self.height, self.width = H, W
        self._depth = depth
        #: The depth image as blocks, a view: (n_rows, BLOCK_PX, n_cols, BLOCK_PX).
        self.depth_blocks = depth.reshape(self.n_rows, b, self.n_cols, b)
        self.y_ref = float(y_ref_per_m)
        self.origin = np.array([W / 2.0, H / 2.0])
        s = 1.0 / COORD_SCALE_PX
        # Frame-wide coordinate powers of every column and row, grouped by block: (blocks, b, 5).
        self._gx = powers_of((np.arange(self.n_cols * b) - self.origin[0]) * s, 4).reshape(self.n_cols, b, 5)
        self._gy = powers_of((np.arange(self.n_rows * b) - self.origin[1]) * s, 4).reshape(self.n_rows, b, 5)
        self._local = powers_of(np.arange(b) - (b - 1) / 2.0, 4)  # (b, 5): in-block offsets, px
        self._sat: tuple | None = None  # (block ranges, table)

    # -- block sums ----------------------------------------------------------------------------
    def _inverse_depth(self, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(valid, y') of pixels (any layout): y' = 1/z - y_ref (float32), 0 where no depth."""
        y, valid = _reciprocal_depth(pix, np.empty(pix.shape, dtype=np.float32))
        y -= np.float32(self.y_ref)
        y *= valid
        return valid, y

    def _to_frame(self, t: np.ndarray, xc: np.ndarray, order: int) -> np.ndarray:
        """Sums over block columns in block-local offsets (px), t[..., r, c] = sum data c_j^r, to
        the frame-wide coordinate: sum data X^p = sum_r C(p, r) xc^(p - r) t_r / scale^r, with
        xc (n_cols,) the columns' centres."""
        s = 1.0 / COORD_SCALE_PX
        pw = powers_of(xc, order - 1)
        out = np.zeros(t.shape)
        for p in range(order):
            for r in range(p + 1):
                out[..., p, :] += (comb(p, r) * s**r) * pw[:, p - r] * t[..., r, :]
        return out

    def _validity_sums(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(len(W_TERMS), k) validity channels of blocks (rows, cols) (k,), pixel by pixel: two
        products in block-local coordinates (shared by all blocks), then the binomial shift to
        each block's centre."""
        b, k = BLOCK_PX, rows.size
        pix = self._depth.reshape(self.n_rows, b, self.n_cols, b)[rows, :, cols, :]  # (k, b, b)
        G = self._local
        w = (pix > 0).astype(np.float64)
        m = ((w.reshape(-1, b) @ G).reshape(k, b, 5).transpose(0, 2, 1).reshape(-1, b) @ G).reshape(k, 5, 5)
        s = 1.0 / COORD_SCALE_PX
        local = {(p, q): m[:, p, q] * s ** (p + q) for p, q in W_TERMS}  # m[p (columns), q (rows)]
        xc = (cols * b + (b - 1) / 2.0 - self.origin[0]) * s
        yc = (rows * b + (b - 1) / 2.0 - self.origin[1]) * s
        shifted = _shift(local, -xc, -yc, W_TERMS, 4)
        return np.stack([shifted[t] for t in W_TERMS])

    def all_blocks(self, rows: tuple[int, int] | None = None, cols: tuple[int, int] | None = None) -> np.ndarray:
        """(N_CHANNELS, rows, cols) sums of every block in the block ranges ``rows``, ``cols``
        ([first, last), default all).

        Over each block's columns one product in block-local offsets, shared by all blocks
        (float32: small exact offsets, no cancellation), shifted to the frame-wide coordinate in
        float64; over its rows one product per block row with the rows' frame-wide powers. The
        validity channels of a block whose pixels all have depth are those of the full block, an
        outer product of its column and row power sums, so while most blocks are whole only those
        with a hole are summed pixel by pixel.
        """
        b = BLOCK_PX
        r_lo, r_hi = rows or (0, self.n_rows)
        c_lo, c_hi = cols or (0, self.n_cols)
        nr, nc = r_hi - r_lo, c_hi - c_lo
        H = nr * b
        valid, y = self._inverse_depth(self._depth[r_lo * b:r_hi * b, c_lo * b:c_hi * b])  # image layout
        out = np.empty((N_CHANNELS, nr, nc))
        nw = len(W_TERMS)
        xc = (np.arange(c_lo, c_hi) * b + (b - 1) / 2.0 - self.origin[0]) / COORD_SCALE_PX
        gy = self._gy[r_lo:r_hi]
        words = valid.view(np.uint64).reshape(nr, b, nc, b // 8)  # eight validity bytes a word
        holed = (words != np.uint64(0x0101010101010101)).any(axis=(1, 3))  # (nr, nc)
        r, c = np.nonzero(holed)
        products = [(y, 3, Y_TERMS, out[nw:-1])]
        if r.size <= _HOLED_BLOCKS_PIXELWISE * holed.size:
            su, sv = self._gx[c_lo:c_hi].sum(axis=1), gy.sum(axis=1)  # (nc, 5[p]), (nr, 5[q])
            for k, (p, q) in enumerate(W_TERMS):
                np.multiply(sv[:, None, q], su[None, :, p], out=out[k])
            if r.size:
                out[:nw, r, c] = self._validity_sums(r + r_lo, c + c_lo)
        else:
            products.append((valid.astype(np.float32), 5, W_TERMS, out[:nw]))
        for data, order, terms, dest in products:
            G = self._local[:, :order].T.astype(np.float32)  # (order, b)
            t = np.matmul(G, np.swapaxes(data.reshape(H, nc, b), 1, 2))  # (H, order[r], nc): over block columns
            t = self._to_frame(t, xc, order).reshape(nr, b, order * nc)
            m = np.matmul(np.swapaxes(gy[:, :, :order], 1, 2), t).reshape(nr, order, order, nc)  # [a, q, p, c]
            for k, (p, q) in enumerate(terms):
                dest[k] = m[:, q, p]
        y *= y  # 64 terms of one sign a block: float32 sums lose nothing that matters
        out[-1] = (y.reshape(H * nc, b) @ np.ones(b, dtype=np.float32)).reshape(nr, b, nc).sum(axis=1)
        return out

    # -- window sums ---------------------------------------------------------------------------
    def _direct_window_sums(self, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray,
                            col1: np.ndarray, step: int = 1) -> WindowSums:
        """The windows' sums from their own pixels, every ``step``-th of each row and column, in
        window-local coordinates (few windows: no table to build). Every window is cut from the
        image as a box of the largest window's size (a view copied row by row), its own pixels
        picked by row and column masks."""
        b, n, s = BLOCK_PX, row0.size, max(int(step), 1)
        kr, kc = int((row1 - row0).max()) * b, int((col1 - col0).max()) * b
        top = np.minimum(row0 * b, self._depth.shape[0] - kr)  # the box stays inside the image
        left = np.minimum(col0 * b, self._depth.shape[1] - kc)
        boxes = np.lib.stride_tricks.sliding_window_view(self._depth, (kr, kc))[:, :, ::s, ::s]  # a view
        pix = boxes[top, left]  # (n, kr / s, kc / s), a copy of the samples only
        centre = self._centres(row0, row1, col0, col1)
        box_r, box_c = np.arange(0, kr, s), np.arange(0, kc, s)  # the samples' rows / columns in the box
        kr, kc = box_r.size, box_c.size
        rows = top[:, None] + box_r  # image row / column of each sample row / column
        cols = left[:, None] + box_c
        in_rows = (rows >= row0[:, None] * b) & (rows < row1[:, None] * b)
        in_cols = (cols >= col0[:, None] * b) & (cols < col1[:, None] * b)
        # Validity and y' of the window's own pixels (0 elsewhere in the box), as two row blocks of
        # one buffer per window.
        data = np.empty((n, 2, kr, kc), dtype=np.float32)
        y, valid = _reciprocal_depth(pix, data[:, 1])
        valid &= in_rows[:, :, None]
        valid &= in_cols[:, None, :]
        data[:, 0] = valid
        y -= np.float32(self.y_ref)
        y *= data[:, 0]
        yr = y.reshape(-1, kc)  # float32 sums of one row each, then float64 over the rows
        yy = np.einsum("ij,ij->i", yr, yr).reshape(n, kr).astype(np.float64).sum(axis=1)
        # Sums over columns then rows of offsets from the box's centre, the same powers for every
        # box: two plain products (float32 over a row, float64 over the rows), then the binomial
        # shift to each window's own centre.
        mid_c, mid_r = 0.5 * (box_c[0] + box_c[-1]), 0.5 * (box_r[0] + box_r[-1])  # the samples' centre
        g_c = powers_of(box_c - mid_c, 4)  # (kc, 5)
        g_r = powers_of(box_r - mid_r, 4)  # (kr, 5)
        t = (data.reshape(-1, kc) @ g_c.astype(np.float32)).astype(np.float64).reshape(n, 2, kr, 5)
        m = (np.ascontiguousarray(np.swapaxes(t, 2, 3)).reshape(-1, kr) @ g_r).reshape(n, 2, 5, 5)  # [p, q]
        du = centre[:, 0] - (left + mid_c)  # each window's centre in its samples' coordinates
        dv = centre[:, 1] - (top + mid_r)
        m = np.matmul(np.matmul(_binomial_shift(du)[:, None], m), np.swapaxes(_binomial_shift(dv), 1, 2)[:, None])
        mw, my = m[:, 0], np.ascontiguousarray(m[:, 1, :3, :3])
        mw[:, np.add.outer(np.arange(5), np.arange(5)) > 4] = 0.0
        my[:, np.add.outer(np.arange(3), np.arange(3)) > 2] = 0.0
        n_window = (self._pixels_in_image(row0, row1, col0, col1) if s == 1
                    else in_rows.sum(axis=1) * in_cols.sum(axis=1))  # the box lies in the image
        return WindowSums(mw=mw, my=my, yy=yy, centre_uv=centre, n_window=n_window, step=s)

    def _centres(self, row0, row1, col0, col1) -> np.ndarray:
        b = BLOCK_PX
        return np.column_stack([(col0 + col1) * b / 2.0 - 0.5, (row0 + row1) * b / 2.0 - 0.5])

    def _pixels_in_image(self, row0, row1, col0, col1) -> np.ndarray:
        b = BLOCK_PX
        rows_in = np.clip(np.minimum(row1 * b, self.height) - row0 * b, 0, None)
        cols_in = np.clip(np.minimum(col1 * b, self.width) - col0 * b, 0, None)
        return rows_in * cols_in

    def summed_area_table(self, rows: tuple[int, int] | None = None,
                          cols: tuple[int, int] | None = None) -> np.ndarray:
        """(N_CHANNELS, rows + 1, cols + 1) cumulative sums of the blocks in the block ranges
        ``rows``, ``cols`` ([first, last), default all): entry [:, i, j] sums the blocks
        [first, first + i) x [first, first + j). Kept for the next call with the same ranges."""
        key = (rows or (0, self.n_rows), cols or (0, self.n_cols))
        if self._sat is None or self._sat[0] != key:
            (r_lo, r_hi), (c_lo, c_hi) = key
            sat = np.zeros((N_CHANNELS, r_hi - r_lo + 1, c_hi - c_lo + 1))
            sat[:, 1:, 1:] = self.all_blocks(*key)
            np.cumsum(sat, axis=2, out=sat)
            for i in range(2, sat.shape[1]):  # row by row: faster than np.cumsum on a middle axis
                sat[:, i] += sat[:, i - 1]
            self._sat = (key, sat)
        return self._sat[1]

    def window_sums(self, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray, col1: np.ndarray,
                    use_table: bool | None = None, step: int = 1) -> WindowSums:
        """Sums over windows of blocks [row0, row1) x [col0, col1) (n,) each (0 <= row0 < row1 <= n_rows).

        ``use_table``: from the summed-area table (True) or from the windows' own pixels (False);
        by default whichever touches fewer blocks. ``step``: the windows' own pixels are sampled
        every ``step``-th row and column (the table sums every pixel: ``WindowSums.step`` says which).
        """
        row0, row1, col0, col1 = (np.asarray(a, dtype=np.int64) for a in (row0, row1, col0, col1))
        nr, nc = row1 - row0, col1 - col0
        n = row0.size
        if use_table is None:  # a sampled pixel costs the direct path more than a table's does: no step here
            use_table = int((nr * nc).sum()) > self.n_rows * self.n_cols
        if n == 0:
            cht = np.zeros((N_CHANNELS, 0))
        elif use_table:
            # A table of just the blocks the windows cover (a part seldom fills the frame).
            r_lo, c_lo = int(row0.min()), int(col0.min())
            S = self.summed_area_table((r_lo, int(row1.max())), (c_lo, int(col1.max())))
            a0, a1, b0, b1 = row0 - r_lo, row1 - r_lo, col0 - c_lo, col1 - c_lo
            cht = S[:, a1, b1] - S[:, a0, b1] - S[:, a1, b0] + S[:, a0, b0]
        else:
            return self._direct_window_sums(row0, row1, col0, col1, step)
        centre = self._centres(row0, row1, col0, col1)
        # Back from the frame-wide coordinate to pixel offsets from each window's centre.
        s = COORD_SCALE_PX
        x0 = (centre[:, 0] - self.origin[0]) / s
        y0 = (centre[:, 1] - self.origin[1]) / s
        wk = _shift({t: cht[k] for k, t in enumerate(W_TERMS)}, x0, y0, W_TERMS, 4)
        yk = _shift({t: cht[len(W_TERMS) + k] for k, t in enumerate(Y_TERMS)}, x0, y0, Y_TERMS, 2)
        mw = np.zeros((n, 5, 5))
        my = np.zeros((n, 3, 3))
        for (p, q), val in wk.items():
            mw[:, p, q] = val * s ** (p + q)
        for (p, q), val in yk.items():
            my[:, p, q] = val * s ** (p + q)
        return WindowSums(mw=mw, my=my, yy=cht[-1].copy(), centre_uv=centre,
                          n_window=self._pixels_in_image(row0, row1, col0, col1))


__all__ = ["BLOCK_PX", "COORD_SCALE_PX", "BlockMoments", "WindowSums", "powers_of"]
