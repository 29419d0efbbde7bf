"""Does a simulated sequence's own truth conserve mass in the image? (the emission acceptance's
precondition)

Run from the repository root on sequences of ``benchmarks/emission_sequences.sh``:

    PYTHONPATH=. python benchmarks/emission_continuity.py DIR/SEQUENCE [...] [--triples N]

On the curtains of ``ogiflow eval emission`` (the chain runs as there), the gas between two
consecutive curtains can only change by what crosses them: dM/dt = Q_k - Q_k+1 (the plume's
sides lie beyond the curtains' ends). M is the simulator's true column density times the
pixel's footprint at the gas's true depth, (Z / s)^2, summed over the pixels between the
two curtains; Q the true flux through each (``processing.emission.truth``), both at the
middle of frames i and i+1. Over all triples and curtain pairs the script prints the
least-squares slope kappa of dM/dt on Q_k - Q_k+1 and their correlation: 1 and 1 when the
truth conserves mass in the image, as any real plume's does. Gas that vanishes in the
middle of the image (through a face of the simulated volume inside the view,
``processing.synthetic.volume_exit``) is a sink this balance does not hold for: the rates of
such a sequence are scored against a truth no image could be consistent with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from appliance.evaluation.emission import iter_triples, sequence_setup
from benchmarks.common import sequence_arguments
from processing.emission.gas import ppm_m_to_kg_m2
from processing.emission.placement import Placement
from processing.emission.truth import true_curtain_flux
from processing.synthetic import SyntheticFrame


def region_masks(placement: Placement, shape: tuple[int, int]) -> list[np.ndarray]:
    """Pixels between curtains k and k+1 (along the plume) within both curtains' ends."""
    d = np.asarray(placement.direction_xy, np.float64)
    perp = np.array([-d[1], d[0]])
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    along, across = xx * d[0] + yy * d[1], xx * perp[0] + yy * perp[1]
    masks = []
    for c0, c1 in zip(placement.curtains, placement.curtains[1:], strict=False):
        a0, a1 = np.asarray(c0.start) @ d, np.asarray(c1.start) @ d
        ends = [np.asarray(p) @ perp for c in (c0, c1) for p in (c.start, c.end)]
        masks.append((along >= a0) & (along < a1) & (across >= min(ends))
                     & (across <= max(ends)))
    return masks


def true_mass_kg(frame: SyntheticFrame, mask: np.ndarray, s: float, t_gas_k: float,
                 molar_mass: float) -> float:
    """Simulated gas mass in the pixels of ``mask``: sigma (Z / s)^2 summed, kg."""
    sigma = ppm_m_to_kg_m2(frame.column_density_ppm_m.astype(np.float64),
                           molar_mass_kg_mol=molar_mass, temperature_k=t_gas_k)
    z = frame.gt_position[..., 2].astype(np.float64)
    z = np.where(np.isfinite(z) & (z > 0), z, 0.0)
    return float(np.sum(np.where(mask, sigma * (z / s) ** 2, 0.0)))


def continuity(directory: Path, triples: int | None) -> tuple[float, float, int]:
    """(kappa, correlation, samples) of dM/dt against Q_k - Q_k+1 (module docstring)."""
    setup = sequence_setup(directory)
    pp, s = setup.geometry.principal_point, setup.geometry.camera_constant
    molar = setup.estimator.settings.gas.molar_mass_kg_mol
    dq, dm = [], []
    for tr in iter_triples(directory, setup, triples):
        p = tr.rates.placement
        if len(p.curtains) < 2:
            continue
        moment = 0.5 * (tr.first.flux_moment_kg_s.astype(np.float64)
                        + tr.second.flux_moment_kg_s.astype(np.float64))
        q = [true_curtain_flux(c, moment, principal_point=pp, camera_constant=s)
             for c in p.curtains]
        dt = tr.second.t_s - tr.first.t_s
        for k, mask in enumerate(region_masks(p, tr.result.gas_mask.shape)):
            m0, m1 = (true_mass_kg(f, mask, s, setup.t_gas_k, molar)
                      for f in (tr.first, tr.second))
            dq.append(q[k] - q[k + 1])
            dm.append((m1 - m0) / dt)
    x, y = np.asarray(dq), np.asarray(dm)
    if len(x) < 3 or not np.any(x):
        return float("nan"), float("nan"), len(x)
    return float(x @ y / (x @ x)), float(np.corrcoef(x, y)[0, 1]), len(x)


def main() -> None:
    args = sequence_arguments(__doc__)
    for seq in args.sequences:
        kappa, corr, n = continuity(seq, args.triples)
        print(f"{seq.name}: dM/dt = kappa (Q_k - Q_k+1) with kappa {kappa:.2f}, "
              f"correlation {corr:.2f} ({n} curtain pairs x triples)", flush=True)


if __name__ == "__main__":
    main()
