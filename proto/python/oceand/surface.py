"""oceand.surface - the whole sea from the streamed cascades (PROTOCOL.md §4.1).

The sea is the sum of up to four periodic patches, cascade c over a square of
side L_c. A Surface holds one frame's grids of every cascade and answers the
summed fields anywhere:

    s = Surface(sim_time, seq, params_version, patch_sizes=[256, 72.25, 20.39],
                grids={0: {"height": h0, "dx": ..., "dz": ...}, 1: {...}, 2: {...}})
    s.sample("height", x, z)          # sum over the cascades at undisplaced points (x, z)
    s.grid("height", 512)             # on a 512 x 512 grid over [0, L_0)^2
    s.displaced_height(x, z)          # height of the displaced surface above (x, z), like `query`

Interpolation ("spectral", the default): every cascade's grid holds a periodic,
band-limited signal (no wavenumber at or above its Nyquist, §4.1), so padding
its spectrum with zeros gives the exact signal on a grid `upsample` times finer;
between those nodes a Catmull-Rom cubic reads it. At a node of a cascade's own
grid its samples are used as they are. Measured against `query` (docs/query.md):
within 0.1 mm at N = 256, 3 cascades. "bilinear" on the streamed grids is ~14 mm
rms off there (the short waves of cascade 0 have 2-4 samples per wavelength) and
is offered only to compare. Cascade 0 at LOD 1 or coarser has lost (aliased) its
shortest waves: off its nodes, read it at LOD 0. The finer cascades lose nothing at LOD 1.
"""
import numpy as np

SUMMED = ("height", "dx", "dz", "slope_x", "slope_z")   # fields that add across cascades (§4.1)
MAX_UPSAMPLED = 4096                                     # side cap of an upsampled grid (64 MiB of float32)


def upsample(grid, factor):
    """The periodic band-limited grid (side s) on a grid `factor` times finer,
    by zero-padding its spectrum. The Nyquist row and column are dropped: the
    server puts no wave there (§4.1), only quantisation noise of lossy tiles."""
    s = grid.shape[0]
    if factor == 1:
        return np.asarray(grid, np.float64)
    m, h = s * factor, s // 2
    f = np.fft.rfft2(np.asarray(grid, np.float64))
    g = np.zeros((m, m // 2 + 1), np.complex128)
    g[:h, :h] = f[:h, :h]
    g[m - h + 1:, :h] = f[s - h + 1:, :h]
    return np.fft.irfft2(g, s=(m, m)) * (factor * factor)


def _catmull_rom(t):
    """Weights of the four samples at offsets -1, 0, 1, 2 for fractions t."""
    t2, t3 = t * t, t * t * t
    return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1, -1.5 * t3 + 2 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


def periodic_cubic(grid, period, x, z):
    """Catmull-Rom interpolation of a periodic grid (row = z) at world points."""
    m = grid.shape[0]
    u, v = np.asarray(x, np.float64) / period * m, np.asarray(z, np.float64) / period * m
    iu, iv = np.floor(u), np.floor(v)
    wu, wv = _catmull_rom(u - iu), _catmull_rom(v - iv)
    iu, iv = iu.astype(np.int64), iv.astype(np.int64)
    out = np.zeros(np.broadcast(u, v).shape)
    for a in range(4):
        row = (iv + a - 1) % m
        acc = np.zeros_like(out)
        for b in range(4):
            acc += wu[b] * grid[row, (iu + b - 1) % m]
        out += wv[a] * acc
    return out


def periodic_bilinear(grid, period, x, z):
    m = grid.shape[0]
    u, v = np.asarray(x, np.float64) / period * m, np.asarray(z, np.float64) / period * m
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    i0, j0 = iu.astype(np.int64) % m, iv.astype(np.int64) % m
    i1, j1 = (i0 + 1) % m, (j0 + 1) % m
    g = np.asarray(grid, np.float64)
    return ((1 - fv) * ((1 - fu) * g[j0, i0] + fu * g[j0, i1]) + fv * ((1 - fu) * g[j1, i0] + fu * g[j1, i1]))


def _on_nodes(grid, period, x, z):
    """The grid's own samples where every point is one of its nodes, else None."""
    m = grid.shape[0]
    u, v = np.asarray(x, np.float64) / period * m, np.asarray(z, np.float64) / period * m
    ru, rv = np.round(u), np.round(v)
    if np.abs(u - ru).max(initial=0) > 1e-6 or np.abs(v - rv).max(initial=0) > 1e-6:
        return None
    return np.asarray(grid, np.float64)[rv.astype(np.int64) % m, ru.astype(np.int64) % m]


class Surface:
    """One frame of the whole sea: grids[c][field] is cascade c's (side x side)
    float32 grid (row = z) over its patch patch_sizes[c]; any LOD (side = N >> lod)."""

    def __init__(self, sim_time, seq, params_version, patch_sizes, grids, upsample_factor=4):
        self.sim_time, self.seq, self.params_version = sim_time, seq, params_version
        self.patch_sizes = [float(p) for p in patch_sizes]
        self.grids = grids
        self.upsample_factor = upsample_factor
        self._fine = {}

    @property
    def cascades(self):
        return sorted(self.grids)

    def fields(self):
        return sorted(set.intersection(*(set(g) for g in self.grids.values()))) if self.grids else []

    def _fine_grid(self, c, name):
        key = (c, name)
        if key not in self._fine:
            g = self.grids[c][name]
            factor = max(1, min(self.upsample_factor, MAX_UPSAMPLED // g.shape[0]))
            self._fine[key] = upsample(g, factor)
        return self._fine[key]

    def sample_cascade(self, c, name, x, z, interpolation="spectral"):
        L, g = self.patch_sizes[c], self.grids[c][name]
        if interpolation == "bilinear":
            return periodic_bilinear(g, L, x, z)
        if interpolation != "spectral":
            raise ValueError(f"interpolation must be spectral or bilinear, not {interpolation!r}")
        exact = _on_nodes(g, L, x, z)
        return exact if exact is not None else periodic_cubic(self._fine_grid(c, name), L, x, z)

    def sample(self, name, x, z, interpolation="spectral"):
        """Field `name` summed over the cascades at undisplaced world points (x, z)."""
        if name not in SUMMED:
            raise ValueError(f"{name} does not add across cascades; sample_cascade() reads one")
        x, z = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(z, np.float64))
        return sum(self.sample_cascade(c, name, x, z, interpolation) for c in self.cascades)

    def grid(self, name, m, origin=(0.0, 0.0), size=None, interpolation="spectral"):
        """The summed field on an m x m grid: point [j, i] at (x0 + i*size/m, z0 + j*size/m);
        size defaults to cascade 0's patch."""
        size = self.patch_sizes[0] if size is None else size
        t = np.arange(m) * (size / m)
        z, x = np.meshgrid(origin[1] + t, origin[0] + t, indexing="ij")
        return self.sample(name, x, z, interpolation).astype(np.float32)

    def displaced_height(self, x, z, interpolation="spectral", iterations=40):
        """Height of the displaced surface above world points (x, z) and the source
        points (x0, z0) with x0 + Dx(x0) = x (what `query` answers as height and source):
        a fixed-point iteration, which converges where the surface does not fold."""
        x, z = np.asarray(x, np.float64), np.asarray(z, np.float64)
        sx, sz = x.copy(), z.copy()
        for _ in range(iterations):
            nx = x - self.sample("dx", sx, sz, interpolation)
            nz = z - self.sample("dz", sx, sz, interpolation)
            done = max(np.abs(nx - sx).max(initial=0), np.abs(nz - sz).max(initial=0)) < 1e-9
            sx, sz = nx, nz
            if done:
                break
        return self.sample("height", sx, sz, interpolation), sx, sz
