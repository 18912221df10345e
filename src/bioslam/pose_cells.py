"""The pose cell network (Sec. III-C, Eq. 10-11): a 3-D continuous attractor network.

``PC[x', y', θ']`` holds one activity packet whose centre encodes the robot pose in cell units.
The three dimensions wrap around, so a small network represents an unbounded space; the
cognitive map (``cognitive_map.py``) resolves the resulting aliasing with the view ids.

One update, as in RatSLAM (Milford 2008; OpenRatSLAM, Ball et al. 2013):

1. ``path_integrate(dp)``  shifts the activity by the odometry (Eq. 10),
2. ``inject_view(...)``    adds the calibration activity of a known view (Eq. 11), or links a
                           new view to the current packet,
3. ``step()``              local excitation, local inhibition (3-D Gaussians), global
                           inhibition and normalisation,
4. ``centre()``            reads the packet centre out (population vector around the peak).

Design choices where the paper is silent, and the OpenRatSLAM pitfalls avoided:

* Kernel variances are floats in cells² (OpenRatSLAM truncates them to integers); the kernels are
  3-D Gaussians ``exp(-d²/2σ²)`` normalised to sum 1, truncated at a configurable radius.
* Path integration works for any step size: each active cell's activity is moved by the real
  shift ``k·Δ`` and spread over the 2x2x2 cube by the fractional residue (Eq. 10 in scatter form);
  OpenRatSLAM's quadrant rotation only supports shifts below one cell per update.
* Updates are sparse: after global inhibition most cells are exactly zero, so path integration
  and injection iterate over the list of active cells only (Numba), and the attractor step
  over the box around them that its excitation reaches, never the whole network unless the
  activity spreads round it.
* Every constant is a named, documented field of ``PoseCellConfig``.
* The discrete attractor pins a packet to the lattice: a packet shifted by a small fraction of
  a cell is pulled partly back by the next ``step`` (measured: it covers only 84% of the
  odometry at 0.05 cell per update). Motion is therefore composed until it amounts to
  ``min_shift_cells`` (default half a cell) before Eq. 10 moves the packet, which keeps the
  packet within 1-4% of the odometry; ``centre`` adds the pending motion to the read-out.
* A view matched on consecutive updates tires (OpenRatSLAM's template decay): its injections
  fade to zero after ~3 updates and recover at ``view_recovery`` per update. So a robot that
  sits still, or drives on while its newest view stays active, does not drag the packet back;
  the packet moves only after a sequence of distinct consecutive matches (measured by
  ``consecutive_matches_to_shift``: 6-7 with the defaults).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.growing import IdRows

FloatArray = NDArray[np.float64]

TWO_PI = 2.0 * math.pi


@dataclass
class PoseCellConfig:
    """Parameters of the pose cell network.

    Defaults follow OpenRatSLAM (Ball et al. 2013, ``config_*.txt.in`` and
    ``posecell_network.cpp``) unless noted; the cell size is chosen for indoor LiDAR.
    """

    #: (n_x, n_y, n_θ) cells; every dimension wraps. OpenRatSLAM: pc_dim_xy = 21, pc_dim_th = 36.
    dims: tuple[int, int, int] = (21, 21, 36)
    #: Edge of a place cell in metres (1/k_x = 1/k_y of Eq. 10). OpenRatSLAM uses 1 m outdoors;
    #: 0.25 m resolves corridors and rooms for an indoor LiDAR robot (a few cells per view change).
    cell_size_xy: float = 0.25
    #: Width of a head-direction layer in radians (1/k_θ of Eq. 10). It must be 2π / n_θ, so that
    #: a full turn brings the packet back to the same layer; ``None`` derives it from ``dims``.
    cell_size_theta: float | None = None
    #: Variance of the excitatory Gaussian in cells² (OpenRatSLAM pc_w_e_var = 1).
    excite_var: float = 1.0
    #: Half-width of the excitatory kernel in cells (OpenRatSLAM pc_w_e_dim = 7 -> 3).
    excite_radius: int = 3
    #: Variance of the inhibitory Gaussian in cells² (OpenRatSLAM pc_w_i_var = 2).
    inhibit_var: float = 2.0
    #: Half-width of the inhibitory kernel in cells (OpenRatSLAM pc_w_i_dim = 5 -> 2).
    inhibit_radius: int = 2
    #: Global inhibition subtracted from every cell after local inhibition; activity below it
    #: becomes exactly zero, which keeps the network sparse (OpenRatSLAM pc_global_inhib).
    global_inhibition: float = 2e-5
    #: k_V of Eq. 11: energy injected by a fully active known view. OpenRatSLAM's
    #: pc_vt_inject_energy = 0.15 (x0.89 for a fresh template); tuned with
    #: ``consecutive_matches_to_shift`` so that one match never moves the packet and a short
    #: run of consecutive matches does (see ``benchmarks/bench_pose_cells.py``).
    view_energy: float = 0.1
    #: Fatigue a view gains per injection; a view keeps injecting
    #: ``max(0, 1 - exp(rate · (fatigue - limit)))`` of its energy, so the same view matched on
    #: consecutive updates (a stationary robot, or the view just learned while the robot
    #: drives on) stops pulling after a few updates. OpenRatSLAM vt_active_decay = 1.0.
    view_fatigue: float = 1.0
    #: Fatigue recovered per update (OpenRatSLAM pc_vt_restore = 0.05).
    view_recovery: float = 0.05
    #: Growth rate of the fatigue term (OpenRatSLAM's exp(1.2 · decay)).
    view_fatigue_rate: float = 1.2
    #: Fatigue at which a view stops injecting: OpenRatSLAM's (30 - exp(1.2 d)) / 30 reaches zero
    #: at d = ln(30) / 1.2.
    view_fatigue_limit: float = math.log(30.0) / 1.2
    #: Odometry is accumulated until it would shift the packet by this many cells (or turn it by
    #: this many layers) before Eq. 10 is applied. The discrete attractor pins a packet to the
    #: lattice, so many sub-cell shifts lag behind the odometry (measured: the packet covers 84%
    #: of the distance at 0.05 cell per update, 99% at 0.5); 0 applies every step at once.
    min_shift_cells: float = 0.5
    #: Half-width, in cells, of the window around the peak used for the population-vector
    #: read-out of the packet centre (OpenRatSLAM PC_CELLS_TO_AVG = 3).
    centre_radius: int = 3
    #: Initial packet centre in cell units; ``None`` = middle of the x/y plane, layer 0 (θ = 0).
    start: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        dims = tuple(int(d) for d in self.dims)
        if len(dims) != 3 or min(dims) < 4:
            raise ValueError(f"pose cell dims must be three sizes >= 4, got {self.dims}")
        self.dims = dims  # type: ignore[assignment]
        if self.cell_size_xy <= 0.0:
            raise ValueError(f"cell_size_xy must be positive, got {self.cell_size_xy}")
        if self.cell_size_theta is None:
            self.cell_size_theta = TWO_PI / dims[2]
        elif not math.isclose(self.cell_size_theta * dims[2], TWO_PI, rel_tol=1e-9):
            raise ValueError(
                f"cell_size_theta ({self.cell_size_theta}) x n_θ ({dims[2]}) must be 2π so that "
                "the heading dimension wraps with the angle"
            )
        if self.excite_var <= 0.0 or self.inhibit_var <= 0.0:
            raise ValueError("kernel variances must be positive")
        if min(self.excite_radius, self.inhibit_radius, self.centre_radius) < 1:
            raise ValueError("kernel and read-out radii must be at least 1 cell")
        if 2 * max(self.excite_radius, self.inhibit_radius, self.centre_radius) + 1 > min(dims):
            raise ValueError(f"kernels wider than the network {dims}")
        if (
            min(
                self.global_inhibition,
                self.view_energy,
                self.view_fatigue,
                self.view_recovery,
                self.min_shift_cells,
            )
            < 0.0
        ):
            raise ValueError("inhibition, view energy/fatigue and min_shift_cells must be >= 0")

    @property
    def cell_size(self) -> tuple[float, float, float]:
        """Cell edges (m, m, rad): 1 / (k_x, k_y, k_θ) of Eq. 10."""
        return (self.cell_size_xy, self.cell_size_xy, float(self.cell_size_theta))


def gaussian_kernel_1d(var: float, radius: int) -> FloatArray:
    """``exp(-d²/2σ²)`` on ``2r+1`` cells, normalised to sum 1: one factor of the separable
    3-D excitation / inhibition weights of Sec. III-C (see ``gaussian_kernel``)."""
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-(offsets**2) / (2.0 * var))
    return w / w.sum()


def gaussian_kernel(var: float, radius: int) -> FloatArray:
    """The 3-D isotropic Gaussian ``exp(-|d|²/2σ²)`` on ``(2r+1)³`` cells, normalised to sum 1:
    the local excitation and inhibition weights of Sec. III-C (RatSLAM's ε and ψ). It is the
    outer product of three ``gaussian_kernel_1d``, which is how ``step`` applies it."""
    g = gaussian_kernel_1d(var, radius)
    return g[:, None, None] * g[None, :, None] * g[None, None, :]


# --- Numba kernels over the flat network, index = (x * n_y + y) * n_θ + θ --------------------


@njit(cache=True)
def _covering_window(occupied, margin):
    """``(start, length)`` of the shortest circular window of an axis that holds every
    occupied coordinate, widened by ``margin`` cells each side; ``(0, n)``, the whole axis,
    once that reaches round. (The window begins after the longest run of empty cells.)"""
    n = occupied.size
    longest, end, run = 0, 0, 0
    for t in range(2 * n):
        if occupied[t % n]:
            if run > longest:
                longest, end = run, t
            run = 0
        else:
            run += 1
    length = n - min(longest, n) + 2 * margin
    if length >= n:
        return 0, n
    return (end - margin) % n, length


@njit(cache=True)
def _convolve_axis(src, dst, g, axis, wrap):
    """``dst = src`` convolved with the 1-D kernel ``g`` along ``axis`` of a box: zero
    beyond the box's ends, or ``wrap`` round them (a box that spans the whole axis). Each
    kernel tap is a shifted multiply-add over the box, a loop the compiler vectorises."""
    lx, ly, lt = src.shape
    n = src.shape[axis]
    r = (g.size - 1) // 2
    dst[:, :, :] = 0.0
    for d in range(-r, r + 1):
        w = g[d + r]
        # dst[c] += w * src[c - d] where c - d lies in the box; wrapped, the rest round it
        for part in range(2 if wrap else 1):
            if part == 0:
                lo, hi, off = max(0, d), min(n, n + d), -d
            elif d > 0:
                lo, hi, off = 0, d, n - d
            elif d < 0:
                lo, hi, off = n + d, n, -d - n
            else:
                continue
            if axis == 0:
                for i in range(lo, hi):
                    for j in range(ly):
                        for k in range(lt):
                            dst[i, j, k] += w * src[i + off, j, k]
            elif axis == 1:
                for i in range(lx):
                    for j in range(lo, hi):
                        for k in range(lt):
                            dst[i, j, k] += w * src[i, j + off, k]
            else:
                for i in range(lx):
                    for j in range(ly):
                        for k in range(lo, hi):
                            dst[i, j, k] += w * src[i, j, k + off]


@njit(cache=True)
def _convolve3(src, dst, spare, g, full_x, full_y, full_t):
    """The separable 3-D Gaussian of ``g``: src -> dst along x, -> spare along y, -> dst
    along θ. ``src`` is left as it was only if it is not ``spare``."""
    # the axes as typed values, not literals: Numba compiles a kernel again for every
    # literal argument, which a first run (an empty cache) pays for
    _convolve_axis(src, dst, g, np.int64(0), full_x)
    _convolve_axis(dst, spare, g, np.int64(1), full_y)
    _convolve_axis(spare, dst, g, np.int64(2), full_t)


@njit(cache=True)
def _attractor_step(pc, active, n_active, g_e, g_i, g_inhib, nx, ny, nt):
    """Excite, inhibit locally, inhibit globally, normalise; returns the new active count.

    The step works on the box of the network that the excitation can reach: the active cells'
    shortest window on each wrapped axis, widened by the excitation kernel's radius. A cell
    outside it is excited by nothing and cannot fire, and the inhibition a cell inside
    receives comes from excited cells, all inside. The 3-D Gaussians are separable: three
    1-D passes over the box each (measured against the active-cell scatter this replaced:
    0.14 against 0.21 ms a step at the median, the same activity to 1e-16).
    """
    r = (g_e.size - 1) // 2
    occupied_x = np.zeros(nx, dtype=np.bool_)
    occupied_y = np.zeros(ny, dtype=np.bool_)
    occupied_t = np.zeros(nt, dtype=np.bool_)
    for t in range(n_active):
        a = active[t]
        occupied_x[a // (nt * ny)] = True
        occupied_y[(a // nt) % ny] = True
        occupied_t[a % nt] = True
    sx, lx = _covering_window(occupied_x, r)
    sy, ly = _covering_window(occupied_y, r)
    st, lt = _covering_window(occupied_t, r)
    box = np.zeros((lx, ly, lt))
    for t in range(n_active):
        a = active[t]
        i, j, k = a // (nt * ny), (a // nt) % ny, a % nt
        box[(i - sx) % nx, (j - sy) % ny, (k - st) % nt] = pc[a]
        pc[a] = 0.0
    spare = np.empty((lx, ly, lt))
    # Local excitation: exc = W_E * PC
    exc = np.empty((lx, ly, lt))
    _convolve3(box, exc, spare, g_e, lx == nx, ly == ny, lt == nt)
    # Local inhibition from the excited state, as OpenRatSLAM: PC = exc - W_I * exc. A cell
    # excited no more than the global inhibition is silenced whatever its neighbours do, so it
    # is left out as a source: its inhibition is below that level (2e-5 of the total).
    for i in range(lx):
        for j in range(ly):
            for k in range(lt):
                v = exc[i, j, k]
                box[i, j, k] = v if v > g_inhib else 0.0
    inh = np.empty((lx, ly, lt))
    _convolve3(box, inh, spare, g_i, lx == nx, ly == ny, lt == nt)
    total = 0.0
    n_new = 0
    for i in range(lx):
        row = ((i + sx) % nx) * ny
        for j in range(ly):
            base = (row + (j + sy) % ny) * nt
            for k in range(lt):
                v = exc[i, j, k] - inh[i, j, k] - g_inhib
                if v > 0.0:
                    idx = base + (k + st) % nt
                    pc[idx] = v
                    total += v
                    active[n_new] = idx
                    n_new += 1
    if total > 0.0:
        for t in range(n_new):
            pc[active[t]] /= total
    return n_new


@njit(cache=True)
def _path_integrate(
    pc, active, n_active, buf, mark, gen, touched, dx, dy, dth, cxy, cth, nx, ny, nt
):
    """Eq. 10 in scatter form: move each active cell by k·Δ (rotated by its layer's heading)
    and spread it over the 2x2x2 cube by the fractional residue."""
    n_out = 0
    sth = dth / cth
    fth = math.floor(sth)
    rth = sth - fth
    for t in range(n_active):
        a = active[t]
        v = pc[a]
        if v == 0.0:
            continue
        k = a % nt
        j = (a // nt) % ny
        i = a // (nt * ny)
        heading = k * cth
        c = math.cos(heading)
        s = math.sin(heading)
        sx = (c * dx - s * dy) / cxy
        sy = (s * dx + c * dy) / cxy
        fx = math.floor(sx)
        fy = math.floor(sy)
        rx = sx - fx
        ry = sy - fy
        i0 = (i + int(fx)) % nx
        j0 = (j + int(fy)) % ny
        k0 = (k + int(fth)) % nt
        for bi in range(2):
            wx = rx if bi == 1 else 1.0 - rx
            if wx == 0.0:
                continue
            ii = i0 + bi if i0 + bi < nx else 0
            for bj in range(2):
                wy = ry if bj == 1 else 1.0 - ry
                if wy == 0.0:
                    continue
                jj = j0 + bj if j0 + bj < ny else 0
                for bk in range(2):
                    wk = rth if bk == 1 else 1.0 - rth
                    if wk == 0.0:
                        continue
                    idx = (ii * ny + jj) * nt + (k0 + bk if k0 + bk < nt else 0)
                    if mark[idx] != gen:
                        mark[idx] = gen
                        buf[idx] = 0.0
                        touched[n_out] = idx
                        n_out += 1
                    buf[idx] += v * wx * wy * wk
    for t in range(n_active):
        pc[active[t]] = 0.0
    for t in range(n_out):
        idx = touched[t]
        pc[idx] = buf[idx]
        buf[idx] = 0.0
        active[t] = idx
    return n_out


@njit(cache=True)
def _inject(pc, active, n_active, mark, gen, cx, cy, cth, energy, nx, ny, nt):
    """Add ``energy`` at a fractional cell position, spread trilinearly over its 2x2x2 cube."""
    fx = math.floor(cx)
    fy = math.floor(cy)
    ft = math.floor(cth)
    rx = cx - fx
    ry = cy - fy
    rt = cth - ft
    for bi in range(2):
        wx = rx if bi == 1 else 1.0 - rx
        ii = (int(fx) + bi) % nx
        for bj in range(2):
            wy = ry if bj == 1 else 1.0 - ry
            jj = (int(fy) + bj) % ny
            for bk in range(2):
                wk = rt if bk == 1 else 1.0 - rt
                e = energy * wx * wy * wk
                if e <= 0.0:
                    continue
                idx = (ii * ny + jj) * nt + (int(ft) + bk) % nt
                if pc[idx] == 0.0 and mark[idx] != gen:
                    mark[idx] = gen
                    active[n_active] = idx
                    n_active += 1
                pc[idx] += e
    return n_active


@njit(cache=True)
def _centre(pc, active, n_active, radius, nx, ny, nt):
    """Population vector around the peak: a circular mean per axis over a (2r+1)³ window."""
    best = -1.0
    bi = 0
    for t in range(n_active):
        if pc[active[t]] > best:
            best = pc[active[t]]
            bi = active[t]
    k = bi % nt
    j = (bi // nt) % ny
    i = bi // (nt * ny)
    sums = np.zeros((3, 2))
    dims = (nx, ny, nt)
    for di in range(-radius, radius + 1):
        ii = (i + di) % nx
        for dj in range(-radius, radius + 1):
            jj = (j + dj) % ny
            for dk in range(-radius, radius + 1):
                kk = (k + dk) % nt
                v = pc[(ii * ny + jj) * nt + kk]
                if v == 0.0:
                    continue
                cells = (ii, jj, kk)
                for ax in range(3):
                    ang = TWO_PI * cells[ax] / dims[ax]
                    sums[ax, 0] += v * math.cos(ang)
                    sums[ax, 1] += v * math.sin(ang)
    out = np.empty(3)
    for ax in range(3):
        ang = math.atan2(sums[ax, 1], sums[ax, 0])
        c = ang * dims[ax] / TWO_PI
        if c < 0.0:
            c += dims[ax]
        # A tiny negative angle rounds to exactly n after the shift; n is cell 0.
        out[ax] = c if c < dims[ax] else 0.0
    return out


def _compose_motion(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a ⊕ b`` for two single relative motions (scalar maths: this runs every update)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def wrapped_cell_distance(a: ArrayLike, b: ArrayLike, dims: tuple[int, int, int]) -> FloatArray:
    """Euclidean distance in cell units between cell coordinates ``(..., 3)``, with wrap-around
    in every dimension (OpenRatSLAM ``get_delta_pc``)."""
    d = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
    n = np.asarray(dims, dtype=np.float64)
    d = np.minimum(np.mod(d, n), n - np.mod(d, n))
    return np.sqrt(np.sum(d * d, axis=-1))


class PoseCellNetwork:
    """The 3-D continuous attractor network of Sec. III-C.

    ``activity`` is the (n_x, n_y, n_θ) array; layer ``k`` of the θ' axis represents the heading
    ``k · cell_size_theta``. Path integration and injection touch only the active (non-zero)
    cells, the attractor step the box around them that its excitation reaches.
    """

    def __init__(self, config: PoseCellConfig | None = None) -> None:
        self.config = config if config is not None else PoseCellConfig()
        cfg = self.config
        self.dims: tuple[int, int, int] = cfg.dims
        size = int(np.prod(self.dims))
        self._pc = np.zeros(size)
        self._shifted = np.zeros(size)
        self._mark = np.zeros(size, dtype=np.int64)
        self._gen = 0
        self._active = np.zeros(size, dtype=np.int64)
        self._touched = np.zeros(size, dtype=np.int64)
        self._n_active = 0
        self._g_e = gaussian_kernel_1d(cfg.excite_var, cfg.excite_radius)
        self._g_i = gaussian_kernel_1d(cfg.inhibit_var, cfg.inhibit_radius)
        #: Link matrix A of Eq. 11, stored sparsely: view id -> the packet centre (cells) at
        #: which the view was learned (rows by view id: 20,000 views an hour, 25 bytes each
        #: instead of a dict entry and an array's 250).
        self.view_links = IdRows(np.float64, 3)
        #: Per view: fatigue and the update count when it was stored; recovery is applied
        #: lazily.
        self._fatigue = IdRows(np.float64)
        self._fatigue_since = IdRows(np.int64)
        self.updates = 0
        #: How often the network lost all activity and was re-seeded at its last centre.
        self.collapses = 0
        self._pending = np.zeros(3)
        start = cfg.start
        if start is None:
            start = (self.dims[0] // 2, self.dims[1] // 2, 0.0)
        self.reset(start)

    # --- state ---------------------------------------------------------------------------

    def reset(self, centre: ArrayLike) -> None:
        """Clear the network and put a single packet at ``centre`` (cell units)."""
        self._pc[:] = 0.0
        self._n_active = 0
        c = np.asarray(centre, dtype=np.float64).reshape(3)
        self._last_centre = c.copy()
        self._n_active = self._inject_at(c, 1.0)
        self.step()

    @property
    def activity(self) -> FloatArray:
        """The activity PC[x', y', θ'] (read-only view)."""
        view = self._pc.reshape(self.dims).view()
        view.flags.writeable = False
        return view

    @property
    def active_count(self) -> int:
        """Number of non-zero cells."""
        return int(self._n_active)

    def _next_gen(self) -> int:
        # Each scattering kernel (path integration, injection) marks the cells it writes with
        # a generation of its own.
        self._gen += 1
        return self._gen

    def _inject_at(self, centre: FloatArray, energy: float) -> int:
        nx, ny, nt = self.dims
        return int(
            _inject(
                self._pc,
                self._active,
                self._n_active,
                self._mark,
                self._next_gen(),
                float(centre[0]),
                float(centre[1]),
                float(centre[2]),
                float(energy),
                nx,
                ny,
                nt,
            )
        )

    # --- Eq. 10 ----------------------------------------------------------------------------

    def path_integrate(self, dp: ArrayLike) -> None:
        """Eq. 10: shift the activity by the odometry ``dp = (dx, dy, dθ)``.

        ``dp`` is the motion in the robot's previous frame (forward, left, turn), of any size.
        Each θ' layer rotates ``(dx, dy)`` by its own heading, so the packet moves along the
        heading it encodes; the shift ``k·Δ`` is split into its integer part and a fractional
        residue spread over the 2x2x2 cube. Motions below ``min_shift_cells`` are composed and
        applied together (``centre`` includes the pending part).
        """
        d = np.asarray(dp, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(d)):
            raise ValueError(f"path integration needs a finite pose change, got {dp}")
        self._pending = _compose_motion(self._pending, d)
        cxy, _, cth = self.config.cell_size
        quantum = self.config.min_shift_cells
        if abs(self._pending[2]) >= quantum * cth:
            self._apply_shift(self._pending)
            self._pending = np.zeros(3)
        elif math.hypot(self._pending[0], self._pending[1]) >= quantum * cxy:
            # Translate now and keep the small turn pending: (x, y, 0) ⊕ (0, 0, θ) = (x, y, θ).
            self._apply_shift(np.array([self._pending[0], self._pending[1], 0.0]))
            self._pending[:2] = 0.0

    def _apply_shift(self, dp: FloatArray) -> None:
        nx, ny, nt = self.dims
        cxy, _, cth = self.config.cell_size
        self._n_active = int(
            _path_integrate(
                self._pc,
                self._active,
                self._n_active,
                self._shifted,
                self._mark,
                self._next_gen(),
                self._touched,
                float(dp[0]),
                float(dp[1]),
                float(dp[2]),
                cxy,
                cth,
                nx,
                ny,
                nt,
            )
        )

    # --- Eq. 11 ----------------------------------------------------------------------------

    def inject_view(self, view_id: int, activity: float = 1.0, is_new: bool = False) -> None:
        """Eq. 11: calibration from the view cells.

        A new view (or one never linked before) learns its link ``A_i`` to the current packet
        centre. A known view injects ``k_V · V_i`` at its linked cells (spread trilinearly over
        the 2x2x2 cube around the stored fractional centre). One injection is too weak to move
        the packet; it only wins after consecutive matches (Sec. III-C's ambiguity rule).
        """
        vid = int(view_id)
        if is_new or vid not in self.view_links:
            self.view_links[vid] = self.centre()
            return
        energy = self.config.view_energy * float(np.clip(activity, 0.0, 1.0))
        energy *= self._fatigue_factor(vid)
        if energy > 0.0:
            self._n_active = self._inject_at(self.view_links[vid], energy)

    def _fatigue_factor(self, vid: int) -> float:
        """Raise the view's fatigue by one injection and return the share it may inject."""
        cfg = self.config
        fatigue, since = 0.0, self.updates
        if vid in self._fatigue:
            fatigue, since = float(self._fatigue[vid]), int(self._fatigue_since[vid])
        fatigue = max(0.0, fatigue - cfg.view_recovery * (self.updates - since))
        # Capped just past the limit, so that a view seen for a long time recovers promptly.
        fatigue = min(fatigue + cfg.view_fatigue, cfg.view_fatigue_limit + cfg.view_fatigue)
        self._fatigue[vid] = fatigue
        self._fatigue_since[vid] = self.updates
        return max(0.0, 1.0 - math.exp(cfg.view_fatigue_rate * (fatigue - cfg.view_fatigue_limit)))

    # --- dynamics and read-out -------------------------------------------------------------

    def step(self) -> None:
        """Local excitation and inhibition (3-D Gaussians), global inhibition, normalisation."""
        cfg = self.config
        self.updates += 1
        nx, ny, nt = self.dims
        self._n_active = int(
            _attractor_step(
                self._pc, self._active, self._n_active, self._g_e, self._g_i,
                cfg.global_inhibition, nx, ny, nt,
            )
        )  # fmt: skip
        if self._n_active == 0:
            # Activity spread thin (e.g. many path integrations without a step) falls below
            # the global inhibition everywhere; re-seed rather than stop the run.
            self.collapses += 1
            self.reset(self._last_centre)

    def centre(self) -> FloatArray:
        """The packet centre (x', y', θ') in cell units, each in [0, n): a population vector
        (circular mean) over the window around the most active cell, as in RatSLAM, plus the
        odometry not yet applied (see ``min_shift_cells``)."""
        nx, ny, nt = self.dims
        c = _centre(self._pc, self._active, self._n_active, self.config.centre_radius, nx, ny, nt)
        self._last_centre = c.copy()
        if np.any(self._pending):
            cxy, _, cth = self.config.cell_size
            heading = c[2] * cth
            dx, dy, dth = self._pending
            c[0] += (math.cos(heading) * dx - math.sin(heading) * dy) / cxy
            c[1] += (math.sin(heading) * dx + math.cos(heading) * dy) / cxy
            c[2] += dth / cth
            c = np.mod(c, self.dims)
        return c

    def centre_distance(self, a: ArrayLike, b: ArrayLike) -> FloatArray:
        """Wrapped distance in cells between two cell positions (see ``wrapped_cell_distance``)."""
        return wrapped_cell_distance(a, b, self.dims)


def consecutive_matches_to_shift(
    config: PoseCellConfig | None = None,
    offset_cells: tuple[float, float, float] = (6.0, 0.0, 0.0),
    view_spacing_cells: float = 1.0,
    speed_cells: float = 0.25,
    max_updates: int = 400,
    activity: float = 1.0,
    tolerance_cells: float = 1.0,
) -> int | None:
    """Measure the ambiguity rule: how many consecutive view matches it takes to move the
    packet to where the views were learned.

    The robot re-drives a straight route (heading 0) whose views were learned every
    ``view_spacing_cells``, but its packet is ``offset_cells`` away from where they were linked
    (accumulated drift, or an aliased place). Each update moves ``speed_cells``, matches the
    view of that stretch and steps the network. Returns the number of matched updates until the
    packet centre is within ``tolerance_cells`` of the route's linked position, or ``None``.
    """
    net = PoseCellNetwork(config)
    cxy = net.config.cell_size[0]
    start = net.centre()
    linked = np.mod(start + np.asarray(offset_cells, dtype=np.float64), net.dims)
    n_views = math.ceil(max_updates * speed_cells / view_spacing_cells) + 2
    for v in range(n_views):
        net.view_links[v] = np.mod(linked + np.array([v * view_spacing_cells, 0.0, 0.0]), net.dims)
    for n in range(1, max_updates + 1):
        net.path_integrate((speed_cells * cxy, 0.0, 0.0))
        travelled = n * speed_cells
        net.inject_view(round(travelled / view_spacing_cells), activity, is_new=False)
        net.step()
        truth = np.mod(linked + np.array([travelled, 0.0, 0.0]), net.dims)
        if net.centre_distance(net.centre(), truth) <= tolerance_cells:
            return n
    return None
