"""3D incompressible buoyant gas flow after Stam's Stable Fluids (paper ref. [22], Sec. 5.1).

The solver advances a velocity field and a gas concentration field on a regular grid with

1. buoyancy (Boussinesq: the gas's density difference to air, weighted by its volume fraction),
2. a gas source (a sphere releasing a known mass rate with an exit velocity, plus seeded
   random perturbations so that every sequence has its own turbulence),
3. semi-Lagrangian advection (backtrace + trilinear interpolation; unconditionally stable),
4. implicit diffusion (Jacobi sweeps of ``(I - k dt L) q = q*``; skipped when ``k == 0``),
5. pressure projection: an exact fast Poisson solve (DST/DCT), so the discrete divergence is
   zero to round-off after every step.

Grid and conventions
--------------------
Axes are those of the left camera (X right, Y down, Z forward); the camera is assumed level, so
gravity points along +Y and buoyant gas rises towards -Y. Arrays are indexed ``[z, y, x]``.
The velocity is stored on a staggered (MAC) grid, which is what makes the projection exact:
``u`` (nz, ny, nx+1) on the X faces, ``v`` (nz, ny+1, nx) on the Y faces, ``w`` (nz+1, ny, nx)
on the Z faces, all in m/s. :meth:`FluidState.cell_velocity` returns the cell-centred field
(3, nz, ny, nx) ordered (X, Y, Z). Cell ``[k, j, i]`` spans ``[i h, (i+1) h] x [j h, (j+1) h]
x [k h, (k+1) h]`` in volume coordinates (metres from the volume's corner).

The concentration is a **mass concentration in kg/m^3** of the released gas (pure gas has
``gas_density_kg_m3``; its volume fraction is ``c / gas_density_kg_m3``).

Boundaries
----------
``"open"``: the volume sits in an ambient flow equal to the wind; a backtrace leaving the
volume reads the wind (velocity) and clean air (concentration), and the pressure is zero
outside (Dirichlet, solved with a type-II DST), so gas leaves freely with the flow.
``"closed"``: a rigid box; the normal velocity on the walls is zero, the pressure has zero
normal gradient (Neumann, type-II DCT), and no gas enters or leaves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from processing.synthetic.advection import advect_all, advect_scalar, diffuse_jacobi
from processing.synthetic.fluid_state import FluidState
from processing.synthetic.projection import project

#: Standard gravity, m/s^2.
GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class GasSource:
    """A spherical gas release.

    Parameters
    ----------
    position_m : (3,) tuple of float
        Centre in volume coordinates (X, Y, Z) in metres from the volume's corner.
    radius_m : float
        Sphere radius in m (at least one cell is always used).
    release_rate_g_s : float
        Mean mass release rate in g/s.
    exit_velocity_m_s : (3,) tuple of float
        Velocity (X, Y, Z) imposed inside the sphere, m/s (Y down: upward is negative).
    turbulence : float
        Scale of the random velocity perturbation drawn at every step in and around the
        source, as a fraction of ``max(|exit_velocity_m_s|, 1 m/s)``: a jet direction that
        wanders (AR(1), correlation ~10 steps) plus white noise per face.
    release_fluctuation : float
        Relative standard deviation of the release (puffing); its mean stays
        ``release_rate_g_s``. Puffs give the concentration texture that differential images
        need.
    release_correlation_s : float
        Correlation time of the release fluctuation, s: the multiplier is
        ``max(0, 1 + release_fluctuation x(t))`` with x an Ornstein-Uhlenbeck process of unit
        variance (a turbulent nozzle's output wanders over fractions of a second; it is not
        re-drawn every step). 0 draws x anew at every step (white puffing).
    """

    position_m: tuple[float, float, float]
    radius_m: float
    release_rate_g_s: float
    exit_velocity_m_s: tuple[float, float, float] = (0.0, -3.0, 0.0)
    turbulence: float = 0.3
    release_fluctuation: float = 0.3
    release_correlation_s: float = 0.7


@dataclass(frozen=True)
class FluidParams:
    """Parameters of the simulation (SI units).

    Parameters
    ----------
    shape : (nz, ny, nx)
        Number of cells along Z, Y, X.
    voxel_m : float
        Edge length of a cubic cell in m (paper: 4 mm).
    dt_s : float
        Time step in s (paper: 1 ms).
    wind_m_s : (3,)
        Ambient wind (X, Y, Z) in the left camera frame, m/s; the initial velocity and, with
        open boundaries, the flow outside the volume.
    boundary : {"open", "closed"}
        See the module docstring.
    viscosity_m2_s, diffusivity_m2_s : float
        Kinematic viscosity of air and gas diffusivity; at these grid sizes the numerical
        diffusion of semi-Lagrangian advection dominates, 0 skips the diffusion solve.
    diffusion_iterations : int
        Jacobi sweeps of the implicit diffusion solve.
    gas_density_kg_m3, air_density_kg_m3 : float
        Densities of the pure gas and of air at the gas temperature (defaults: methane and
        air at 15 degC, 1 atm). Buoyant acceleration is ``g (1 - rho_g / rho_air) c / rho_g``.
    sources : tuple of GasSource
    """

    shape: tuple[int, int, int] = (100, 100, 100)
    voxel_m: float = 0.004
    dt_s: float = 0.001
    wind_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    boundary: str = "open"
    viscosity_m2_s: float = 1.5e-5
    diffusivity_m2_s: float = 2.0e-5
    diffusion_iterations: int = 4
    gas_density_kg_m3: float = 0.679
    air_density_kg_m3: float = 1.225
    sources: tuple[GasSource, ...] = field(default_factory=tuple)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        if len(self.shape) != 3 or any(int(n) < 4 for n in self.shape):
            raise ValueError(f"shape must be 3 sizes >= 4, got {self.shape!r}")
        if not self.voxel_m > 0 or not self.dt_s > 0:
            raise ValueError(f"voxel_m and dt_s must be > 0, got {self.voxel_m}, {self.dt_s}")
        if self.boundary not in ("open", "closed"):
            raise ValueError(f"boundary must be 'open' or 'closed', got {self.boundary!r}")
        if len(self.wind_m_s) != 3 or not all(math.isfinite(x) for x in self.wind_m_s):
            raise ValueError(f"wind_m_s must be 3 finite numbers, got {self.wind_m_s!r}")
        if self.boundary == "closed" and any(x != 0.0 for x in self.wind_m_s):
            raise ValueError("a closed box cannot have a wind; use boundary='open'")
        if self.viscosity_m2_s < 0 or self.diffusivity_m2_s < 0:
            raise ValueError("viscosity_m2_s and diffusivity_m2_s must be >= 0")
        if not (self.gas_density_kg_m3 > 0 and self.air_density_kg_m3 > 0):
            raise ValueError("densities must be > 0")
        extent = np.array(self.shape[::-1], dtype=float) * self.voxel_m
        for s in self.sources:
            p = np.asarray(s.position_m, dtype=float)
            if p.shape != (3,) or np.any(p < 0) or np.any(p > extent):
                raise ValueError(f"source position {s.position_m} is outside the volume {extent}")
            if not s.radius_m > 0 or s.release_rate_g_s < 0:
                raise ValueError("source radius must be > 0 and release rate >= 0")
            if s.release_correlation_s < 0:
                raise ValueError("release_correlation_s must be >= 0")


def initial_state(params: FluidParams) -> FluidState:
    """State at t = 0: no gas, velocity equal to the wind everywhere."""
    params.validate()
    nz, ny, nx = (int(n) for n in params.shape)
    wx, wy, wz = params.wind_m_s
    return FluidState(
        u=np.full((nz, ny, nx + 1), wx),
        v=np.full((nz, ny + 1, nx), wy),
        w=np.full((nz + 1, ny, nx), wz),
        c=np.zeros((nz, ny, nx)),
    )


# --------------------------------------------------------------------------------------------
# forces and sources


def _source_mask(params: FluidParams, source: GasSource, dilate_m: float = 0.0) -> np.ndarray:
    """Boolean (nz, ny, nx) of the cells whose centre lies in the (dilated) source sphere."""
    nz, ny, nx = params.shape
    h = params.voxel_m
    z, y, x = np.ogrid[:nz, :ny, :nx]
    px, py, pz = source.position_m
    d2 = ((x + 0.5) * h - px) ** 2 + ((y + 0.5) * h - py) ** 2 + ((z + 0.5) * h - pz) ** 2
    mask = d2 <= (source.radius_m + dilate_m) ** 2
    if not mask.any():  # a sub-voxel source still occupies its cell
        mask[
            min(int(pz / h), nz - 1), min(int(py / h), ny - 1), min(int(px / h), nx - 1)
        ] = True
    return mask


def _faces_of(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face masks (u, v, w shapes) of faces touching at least one masked cell."""
    nz, ny, nx = mask.shape
    mu = np.zeros((nz, ny, nx + 1), dtype=bool)
    mu[:, :, 1:] |= mask
    mu[:, :, :-1] |= mask
    mv = np.zeros((nz, ny + 1, nx), dtype=bool)
    mv[:, 1:, :] |= mask
    mv[:, :-1, :] |= mask
    mw = np.zeros((nz + 1, ny, nx), dtype=bool)
    mw[1:, :, :] |= mask
    mw[:-1, :, :] |= mask
    return mu, mv, mw


def add_buoyancy(state: FluidState, params: FluidParams, dt: float) -> None:
    """Boussinesq buoyancy on the Y faces: ``dv = -g (1 - rho_g/rho_air) phi dt`` (Y down)."""
    beta = 1.0 - params.gas_density_kg_m3 / params.air_density_kg_m3
    phi = state.c / params.gas_density_kg_m3
    face = np.zeros_like(state.v)
    face[:, 1:-1, :] = 0.5 * (phi[:, 1:, :] + phi[:, :-1, :])
    state.v -= GRAVITY_M_S2 * beta * dt * face


class FluidSimulation:
    """A Stable-Fluids gas simulation; :meth:`step` advances it by ``params.dt_s``.

    Parameters
    ----------
    params : FluidParams
    seed : int
        Seed of the source turbulence and release fluctuation.
    state : FluidState, optional
        Start state (default: :func:`initial_state`).
    """

    def __init__(self, params: FluidParams, seed: int = 0, state: FluidState | None = None):
        params.validate()
        self.params = params
        self.rng = np.random.default_rng(seed)
        self.state = state if state is not None else initial_state(params)
        self._wind = np.asarray(params.wind_m_s, dtype=float)
        self._src = []
        for s in params.sources:
            cells = _source_mask(params, s)
            halo = _faces_of(_source_mask(params, s, dilate_m=2 * params.voxel_m))
            self._src.append((s, cells, _faces_of(cells), halo))
        self._jet_dir = [np.zeros(3) for _ in params.sources]
        # Ornstein-Uhlenbeck state of each source's release, started in its stationary law.
        self._release_x = [float(self.rng.standard_normal()) for _ in params.sources]
        #: Gas mass released since the start (spin-up included), kg: the ground truth of
        #: the release rate over any interval is the difference of two readings.
        self.released_kg = 0.0
        #: False while a scheduled release is off (processing.synthetic.schedule): the
        #: sources then release no gas and force no jet; gas already out drifts on.
        self.release_on = True

    @property
    def wind_m_s(self) -> np.ndarray:
        """Current ambient wind (X, Y, Z), m/s."""
        return self._wind.copy()

    def set_wind(self, wind_m_s: np.ndarray | tuple[float, float, float]) -> None:
        """Change the ambient wind (open boundaries only); it acts through the boundaries."""
        wind = np.asarray(wind_m_s, dtype=float)
        if wind.shape != (3,) or not np.all(np.isfinite(wind)):
            raise ValueError(f"wind must be 3 finite numbers, got {wind_m_s!r}")
        if self.params.boundary == "closed" and np.any(wind != 0):
            raise ValueError("a closed box cannot have a wind")
        self._wind = wind

    def _apply_sources(self, dt: float) -> None:
        if not self.release_on:
            return
        st, p = self.state, self.params
        h3 = p.voxel_m**3
        for n, (src, cells, faces, halo) in enumerate(self._src):
            exit_v = np.asarray(src.exit_velocity_m_s, dtype=float)
            sigma = src.turbulence * max(float(np.linalg.norm(exit_v)), 1.0)
            # A slowly wandering jet direction (random walk with relaxation) gives the plume
            # large-scale meanders; per-face noise in a halo seeds small eddies.
            self._jet_dir[n] = 0.9 * self._jet_dir[n] + 0.3 * sigma * self.rng.standard_normal(3)
            jet = exit_v + self._jet_dir[n]
            for comp, (arr, fm, hm) in enumerate(zip((st.u, st.v, st.w), faces, halo, strict=True)):
                arr[fm] = jet[comp] + 0.5 * sigma * self.rng.standard_normal(int(fm.sum()))
                ring = hm & ~fm
                arr[ring] += 0.5 * sigma * self.rng.standard_normal(int(ring.sum()))
            factor = max(0.0, 1.0 + src.release_fluctuation * self._release_step(n, src, dt))
            mass_kg = src.release_rate_g_s * 1e-3 * dt * factor
            st.c[cells] += mass_kg / (cells.sum() * h3)
            self.released_kg += mass_kg

    def _release_step(self, n: int, src: GasSource, dt: float) -> float:
        """Advance source ``n``'s Ornstein-Uhlenbeck release state by ``dt``; return it.

        Exact discretisation x <- a x + sqrt(1 - a^2) N(0, 1), a = exp(-dt / tau), so the
        variance stays 1 whatever the step (the spin-up's steps are longer).
        """
        tau = src.release_correlation_s
        a = math.exp(-dt / tau) if tau > 0 else 0.0
        x = a * self._release_x[n] + math.sqrt(1.0 - a * a) * float(self.rng.standard_normal())
        self._release_x[n] = x
        return x

    def step(self) -> None:
        """Advance by one time step ``params.dt_s`` (forces, advection, diffusion, projection)."""
        p, st = self.params, self.state
        dt, h = p.dt_s, p.voxel_m
        is_open = p.boundary == "open"
        add_buoyancy(st, p, dt)
        self._apply_sources(dt)
        if not is_open:  # walls: no flow through the box's faces
            st.u[:, :, 0] = st.u[:, :, -1] = 0.0
            st.v[:, 0, :] = st.v[:, -1, :] = 0.0
            st.w[0, :, :] = st.w[-1, :, :] = 0.0
        # velocity: self-advection, viscosity, projection
        u1, v1, w1 = np.empty_like(st.u), np.empty_like(st.v), np.empty_like(st.w)
        advect_all(st.u, st.v, st.w, dt / h, is_open, self._wind, u1, v1, w1)
        if p.viscosity_m2_s > 0:
            a = p.viscosity_m2_s * dt / h**2
            for arr in (u1, v1, w1):
                diffuse_jacobi(arr.copy(), a, p.diffusion_iterations, arr)
        if not is_open:
            u1[:, :, 0] = u1[:, :, -1] = 0.0
            v1[:, 0, :] = v1[:, -1, :] = 0.0
            w1[0, :, :] = w1[-1, :, :] = 0.0
        st.u, st.v, st.w = u1, v1, w1
        project(st, h, p.boundary)
        # gas: carried by the new (divergence-free) velocity, then diffused
        c1 = np.empty_like(st.c)
        advect_scalar(st.c, st.u, st.v, st.w, dt / h, is_open, 0.0, c1)
        if p.diffusivity_m2_s > 0:
            diffuse_jacobi(c1.copy(), p.diffusivity_m2_s * dt / h**2, p.diffusion_iterations, c1)
        st.c = c1
        st.t_s += dt
