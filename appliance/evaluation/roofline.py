"""A roofline-style floor for the chain: bytes streamed per triple over memory bandwidth.

The variational solvers (paper Eq. 5, 6) are memory-bound: a red-black SOR sweep does about
20 flops per pixel on about 76 bytes. :func:`triple_bytes` counts the bytes each solver
kernel streams per triple if every array it touches is read or written exactly once per
pass (no cache reuse between passes), from the solvers' actual iteration counts and pyramid
shapes; :func:`copy_bandwidth` measures how fast this machine streams memory (a numpy copy,
read + write), once with a working set the size of the finest level's linear system
(cache-resident on a CPU with a large last-level cache) and once far beyond any cache.
bytes / bandwidth is a floor: no implementation that streams its arrays can run faster.

The per-pass counts (float32 arrays of one colour per pixel, both colours together):

- one SOR iteration: 13 coefficient planes read, 2 unknowns read and written, 2
  neighbouring unknowns read: 19 arrays;
- one lagged iteration (psi', edge weights, data terms, diagonals) outside SOR: about 50;
- one warp outside the lagged iterations (warping, derivatives, splitting): about 40 for the
  flow and 35 for the disparity;
- the rest of the chain (pre-processing of one new frame per camera, velocity, quality,
  segmentation, summary): about 120 full-size arrays.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from processing.chain.state import solver_options
from processing.flow.brox import brox_optical_flow
from processing.solvers.pyramid import pyramid_shapes
from processing.stereo.joint import joint_disparity

BYTES = 4  # float32
SOR_ARRAYS = 19
LAGGED_ARRAYS = 50
FLOW_WARP_ARRAYS = 40
DISPARITY_WARP_ARRAYS = 35
OTHER_ARRAYS = 120


@dataclass(frozen=True)
class Floor:
    """Bytes per triple, measured bandwidths (GB/s) and the resulting floors (ms)."""

    bytes_per_triple: float
    cache_bandwidth_gb_s: float
    dram_bandwidth_gb_s: float

    @property
    def cache_floor_ms(self) -> float:
        """Time to stream the bytes at the cache-resident bandwidth."""
        return self.bytes_per_triple / (self.cache_bandwidth_gb_s * 1e9) * 1e3

    @property
    def dram_floor_ms(self) -> float:
        """Time to stream the bytes from main memory."""
        return self.bytes_per_triple / (self.dram_bandwidth_gb_s * 1e9) * 1e3


def _solver_bytes(shape: tuple[int, int], options: Mapping[str, Any], defaults: Mapping[str, Any],
                  warp_arrays: int) -> float:

    o = {**defaults, **options}
    shapes = pyramid_shapes(shape, o["pyramid_factor"], min(o["min_level_size"], min(shape)))
    if o.get("n_levels") is not None:
        shapes = shapes[:o["n_levels"]]
    total = 0.0
    for level, (h, w) in enumerate(shapes):
        if level < o.get("finest_level", 0):
            continue  # interpolated, not solved
        finest = level == 0
        warps = o.get("n_warps_finest", o["n_warps"]) if finest else o["n_warps"]
        inner = o.get("n_inner_finest", o["n_inner"]) if finest else o["n_inner"]
        per_warp = warp_arrays + inner * (LAGGED_ARRAYS + o["n_sor"] * SOR_ARRAYS)
        total += warps * per_warp * h * w * BYTES
    return total


def _defaults(func: Any) -> dict[str, Any]:
    return {k: p.default for k, p in inspect.signature(func).parameters.items()
            if p.default is not inspect.Parameter.empty}


def triple_bytes(shape: tuple[int, int], params: Any, *, warm: bool) -> float:
    """Bytes streamed per triple by the chain with ``params`` (a ChainParameters), (H, W)."""

    flow = solver_options(params.flow_options, params.warm_flow_options, warm)
    disp = solver_options(params.disparity_options, params.warm_disparity_options, warm)
    h, w = shape
    return (_solver_bytes(shape, flow, _defaults(brox_optical_flow), FLOW_WARP_ARRAYS)
            + _solver_bytes(shape, disp, _defaults(joint_disparity), DISPARITY_WARP_ARRAYS)
            + OTHER_ARRAYS * h * w * BYTES)


def copy_bandwidth(nbytes: int, *, repeats: int = 20) -> float:
    """Best read + write bandwidth of ``np.copyto`` over ``nbytes``-sized arrays, GB/s."""
    n = max(1, nbytes // 8)
    src = np.ones(n, np.float64)
    dst = np.empty_like(src)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        np.copyto(dst, src)
        best = min(best, time.perf_counter() - t)
    return 2.0 * src.nbytes / best / 1e9


def floor(shape: tuple[int, int], params: Any, *, warm: bool = True) -> Floor:
    """The floor of one triple: :func:`triple_bytes` over both measured bandwidths."""
    h, w = shape
    system = 2 * 13 * (h + 2) * ((w + 1) // 2 + 2) * BYTES  # finest level, both colours
    return Floor(bytes_per_triple=triple_bytes(shape, params, warm=warm),
                 cache_bandwidth_gb_s=copy_bandwidth(system // 2),
                 dram_bandwidth_gb_s=copy_bandwidth(256 * 1024 * 1024, repeats=5))
