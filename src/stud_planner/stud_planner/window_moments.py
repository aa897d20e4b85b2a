"""Moment sums of inverse depth over block-aligned windows: one pass over the frame, then O(1) per window.

The least-squares quadric fit of 1/z over a window (:mod:`stud_planner.surface_pose`) needs only sums
over the window's valid pixels: of u^p v^q (p + q <= 4), of y u^p v^q (p + q <= 2, y = 1/z) and of
y^2. Those sums are additive over any partition of the window, so the image is cut into square
blocks of :data:`BLOCK_PX` pixels, each block's sums are computed once (a few BLAS products per
frame), and a window made of whole blocks gets its sums either by adding its blocks (few windows)
or from summed-area tables of the block sums (many windows: four look-ups per channel). Both give
the same numbers up to rounding; which one runs is a matter of cost only.

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
#: Up to this fraction of blocks with a hole, their validity sums are taken pixel by pixel and
#: the whole blocks' in closed form; beyond it, one product over the whole image is cheaper.
_HOLED_BLOCKS_PIXELWISE = 0.3


@dataclass(frozen=True)
class WindowSums:
    """Sums over the valid pixels of n windows, about each window's centre, in pixels.

    ``mw`` (n, 5, 5) [p, q] = sum u'^p v'^q (entries with p + q > 4 are 0); ``my`` (n, 3, 3)
    [p, q] = sum y' u'^p v'^q (p + q <= 2); ``yy`` (n,) = sum y'^2; with u', v' the pixel offsets
    from the window's centre and y' = 1/z - y_ref (1/m). ``centre_uv`` (n, 2) px, ``n_window`` (n,)
    pixels of the window inside the image.
    """

    mw: np.ndarray
    my: np.ndarray
    yy: np.ndarray
    centre_uv: np.ndarray
    n_window: np.ndarray


def _powers(x: np.ndarray, order: int) -> np.ndarray:
    """x[..., None] ** (0..order), (..., order + 1)."""
    out = np.empty(np.shape(x) + (order + 1,))
    out[..., 0] = 1.0
    for k in range(1, order + 1):
        out[..., k] = out[..., k - 1] * x
    return out


_W_INDEX = np.array([p * 5 + q for p, q in W_TERMS])
_Y_INDEX = np.array([p * 3 + q for p, q in Y_TERMS])


def _shift(ch: dict, x0: np.ndarray, y0: np.ndarray, terms, order: int) -> dict:
    """Moments about (x0, y0) from moments about the origin: sum (x - x0)^p (y - y0)^q, for the
    (p, q) in ``terms``; ``ch`` maps (p, q) -> (n,) arrays. Binomial expansion, u then v."""
    px, py = _powers(-x0, order), _powers(-y0, order)
    half = {}
    for p, q in terms:  # sum (x - x0)^p y^q
        half[p, q] = sum(comb(p, r) * px[:, p - r] * ch[r, q] for r in range(p + 1))
    return {(p, q): sum(comb(q, s) * py[:, q - s] * half[p, s] for s in range(q + 1)) for p, q in terms}


class BlockMoments:
    """Per-block sums of one depth image, computed on demand (a set of blocks, or all of them).

    ``depth_m`` (H, W) metres, NaN (or <= 0) = no depth; ``y_ref_per_m`` the inverse depth the
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
        self.y_ref = float(y_ref_per_m)
        self.origin = np.array([W / 2.0, H / 2.0])
        s = 1.0 / COORD_SCALE_PX
        # Frame-wide coordinate powers of every column and row, grouped by block: (blocks, b, 5).
        self._gx = _powers((np.arange(self.n_cols * b) - self.origin[0]) * s, 4).reshape(self.n_cols, b, 5)
        self._gy = _powers((np.arange(self.n_rows * b) - self.origin[1]) * s, 4).reshape(self.n_rows, b, 5)
        self._local = _powers(np.arange(b) - (b - 1) / 2.0, 4)  # (b, 5): in-block offsets, px
        self._sat: np.ndarray | None = None

    # -- block sums ----------------------------------------------------------------------------
    def _inverse_depth(self, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(valid, y', y' as float32) of pixels (any layout): y' = 1/z - y_ref, 0 where no depth."""
        z = np.fmin(pix, np.float32(np.inf))  # NaN -> inf (and a contiguous copy): 1/z is then 0
        y = np.divide(np.float32(1.0), z, out=z)
        valid = (y > 0) & (y < np.inf)  # no depth: NaN, 0 or negative
        y -= np.float32(self.y_ref)
        y *= valid
        return valid, y.astype(np.float64), y

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

    def all_blocks(self) -> np.ndarray:
        """(N_CHANNELS, n_rows, n_cols) sums of every block.

        Products batched over block columns and then block rows (a column's coordinate powers
        are shared down it, a row's along it). The validity channels of a block whose pixels all
        have depth are those of the full block, an outer product of its column and row power
        sums, so while most blocks are whole only those with a hole are summed pixel by pixel.
        """
        b, nr, nc = BLOCK_PX, self.n_rows, self.n_cols
        valid, y, y32 = self._inverse_depth(self._depth.reshape(nr * b, nc, b).transpose(1, 0, 2))  # (nc, H, b)
        out = np.empty((N_CHANNELS, nr, nc))
        nw = len(W_TERMS)
        all_valid = np.uint64(0x0101010101010101)  # eight True bytes
        holed = (valid.view(np.uint64).reshape(nc, nr, b * b // 8) != all_valid).any(axis=2).T  # (nr, nc)
        r, c = np.nonzero(holed)
        products = [(y, 3, _Y_INDEX, out[nw:-1])]
        if r.size <= _HOLED_BLOCKS_PIXELWISE * holed.size:
            su, sv = self._gx.sum(axis=1), self._gy.sum(axis=1)  # (nc, 5[p]), (nr, 5[q])
            for k, (p, q) in enumerate(W_TERMS):
                np.multiply(sv[:, None, q], su[None, :, p], out=out[k])
            if r.size:
                out[:nw, r, c] = self._validity_sums(r, c)
        else:
            products.append((valid.astype(np.float64), 5, _W_INDEX, out[:nw]))
        for data, order, index, dest in products:
            t = np.matmul(data, self._gx[:, :, :order])  # (nc, H, order[p])
            t = t.reshape(nc, nr, b, order).transpose(1, 0, 3, 2).reshape(nr, nc * order, b)
            m = np.matmul(t, self._gy[:, :, :order]).reshape(nr, nc, order * order)  # [p * order + q]
            dest[...] = m.transpose(2, 0, 1)[index]
        yb = y32.reshape(nc * nr, b * b)  # 64 terms of one sign: float32 sums lose nothing that matters
        out[-1] = np.einsum("kj,kj->k", yb, yb).reshape(nc, nr).T
        return out

    def blocks(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N_CHANNELS, k) sums of blocks (rows, cols) (k,), in the frame-wide coordinate."""
        b, k = BLOCK_PX, rows.size
        pix = self._depth.reshape(self.n_rows, b, self.n_cols, b)[rows, :, cols, :]  # (k, b, b)
        _, y, _ = self._inverse_depth(pix)
        gx, gy = self._gx[cols, :, :3], self._gy[rows, :, :3]
        my = np.matmul(np.swapaxes(gy, 1, 2), np.matmul(y, gx))  # (k, 3[q], 3[p])
        out = np.empty((N_CHANNELS, k))
        nw = len(W_TERMS)
        out[:nw] = self._validity_sums(rows, cols)
        out[nw:-1] = np.swapaxes(my, 1, 2).reshape(k, 9)[:, _Y_INDEX].T
        yb = y.reshape(k, -1)
        out[-1] = np.einsum("kj,kj->k", yb, yb)
        return out

    # -- window sums ---------------------------------------------------------------------------
    def _direct_window_sums(self, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray,
                            col1: np.ndarray) -> WindowSums:
        """The windows' sums from their own pixels, in window-local coordinates (few windows: no
        table to build). Windows of one size share their coordinate powers: two products each."""
        b, n = BLOCK_PX, row0.size
        mw, my, yy = np.zeros((n, 5, 5)), np.zeros((n, 3, 3)), np.zeros(n)
        size = (row1 - row0) * (self.n_cols + 1) + (col1 - col0)
        for key in np.unique(size):
            j = np.flatnonzero(size == key)
            kr, kc = (row1[j[0]] - row0[j[0]]) * b, (col1[j[0]] - col0[j[0]]) * b
            # Whole windows as views of the image, copied row by row: (k, kr, kc).
            pix = np.lib.stride_tricks.sliding_window_view(self._depth, (kr, kc))[row0[j] * b, col0[j] * b]
            valid, y, _ = self._inverse_depth(pix)
            gu = _powers(np.arange(kc) - (kc - 1) / 2.0, 4)
            gv = _powers(np.arange(kr) - (kr - 1) / 2.0, 4)
            k = j.size
            w = valid.astype(np.float64)
            mw[j] = ((w.reshape(-1, kc) @ gu).reshape(k, kr, 5).transpose(0, 2, 1).reshape(-1, kr)
                     @ gv).reshape(k, 5, 5)
            my[j] = ((y.reshape(-1, kc) @ gu[:, :3]).reshape(k, kr, 3).transpose(0, 2, 1).reshape(-1, kr)
                     @ gv[:, :3]).reshape(k, 3, 3)
            yf = y.reshape(k, -1)
            yy[j] = np.einsum("kj,kj->k", yf, yf)
        mw[:, np.add.outer(np.arange(5), np.arange(5)) > 4] = 0.0
        my[:, np.add.outer(np.arange(3), np.arange(3)) > 2] = 0.0
        return WindowSums(mw=mw, my=my, yy=yy, centre_uv=self._centres(row0, row1, col0, col1),
                          n_window=self._pixels_in_image(row0, row1, col0, col1))

    def _centres(self, row0, row1, col0, col1) -> np.ndarray:
        b = BLOCK_PX
        return np.column_stack([(col0 + col1) * b / 2.0 - 0.5, (row0 + row1) * b / 2.0 - 0.5])

    def _pixels_in_image(self, row0, row1, col0, col1) -> np.ndarray:
        b = BLOCK_PX
        rows_in = np.clip(np.minimum(row1 * b, self.height) - row0 * b, 0, None)
        cols_in = np.clip(np.minimum(col1 * b, self.width) - col0 * b, 0, None)
        return rows_in * cols_in

    def summed_area_table(self) -> np.ndarray:
        """(N_CHANNELS, n_rows + 1, n_cols + 1) cumulative block sums, built once."""
        if self._sat is None:
            sat = np.zeros((N_CHANNELS, self.n_rows + 1, self.n_cols + 1))
            sat[:, 1:, 1:] = self.all_blocks()
            np.cumsum(sat, axis=2, out=sat)
            for i in range(2, self.n_rows + 1):  # row by row: faster than np.cumsum on a middle axis
                sat[:, i] += sat[:, i - 1]
            self._sat = sat
        return self._sat

    def window_sums(self, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray, col1: np.ndarray,
                    use_table: bool | None = None) -> WindowSums:
        """Sums over windows of blocks [row0, row1) x [col0, col1) (n,) each (0 <= row0 < row1 <= n_rows).

        ``use_table``: from the summed-area table (True) or by adding the windows' blocks (False);
        by default whichever touches fewer blocks.
        """
        row0, row1, col0, col1 = (np.asarray(a, dtype=np.int64) for a in (row0, row1, col0, col1))
        nr, nc = row1 - row0, col1 - col0
        n = row0.size
        if use_table is None:
            use_table = int((nr * nc).sum()) > self.n_rows * self.n_cols
        if n == 0:
            cht = np.zeros((N_CHANNELS, 0))
        elif use_table:
            S = self.summed_area_table()
            cht = S[:, row1, col1] - S[:, row0, col1] - S[:, row1, col0] + S[:, row0, col0]
        else:
            return self._direct_window_sums(row0, row1, col0, col1)
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


__all__ = ["BLOCK_PX", "COORD_SCALE_PX", "BlockMoments", "WindowSums"]
