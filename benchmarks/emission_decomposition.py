"""Which input of the emission rate is wrong: each replaced by the simulator's truth in turn.

Run from the repository root on sequences of ``benchmarks/emission_sequences.sh``:

    PYTHONPATH=. python benchmarks/emission_decomposition.py DIR/SEQUENCE [...] [--triples N]

For every triple the chain runs as in ``ogiflow eval emission``; on the same curtains the
stereo rate is then recomputed with one of its inputs replaced, where the simulator has gas,
by the truth of ``processing.synthetic.reference.eq4_reference`` (the (u, v, d, d') that Eq. 4
turns into the true concentration-weighted velocity at the true virtual surface) or by the
true column density: the flow w, the disparity d, the disparity change d' (i.e. V_Z), sigma,
and all four. Prints, per sequence, the error of each against the true curtain flux (mean
over triples and curtains, as ``eval emission``) and the per-curtain errors (curtain 0 is
nearest the source). The input whose truth removes the error is the one that causes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from appliance.evaluation.emission import iter_triples, sequence_setup
from benchmarks.common import sequence_arguments
from processing.emission.curtains import curtain_flux
from processing.emission.gas import ppm_m_to_kg_m2
from processing.emission.truth import true_curtain_flux
from processing.synthetic.reference import eq4_reference
from processing.velocity.triangulate import scene_flow_velocity

INPUTS = ("measured", "true w", "true d", "true d'", "true sigma", "all true")


def _pick(has: np.ndarray, measured: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``truth`` where the simulator has gas (``has``), ``measured`` elsewhere, float32."""
    m = has if measured.ndim == 2 else has[..., None]
    return np.where(m, np.nan_to_num(truth), measured).astype(np.float32)


def decompose(directory: Path, triples: int | None) -> dict[str, np.ndarray]:
    """Per (triple, curtain): the true flux and the rate with each input of ``INPUTS``, g/s."""
    setup = sequence_setup(directory)
    est, t_gas = setup.estimator, setup.t_gas_k
    gas = est.settings.gas
    geom = setup.geometry
    pp, s, b = geom.principal_point, geom.camera_constant, geom.baseline
    rows: dict[str, list[list[float]]] = {k: [] for k in ("truth", *INPUTS)}
    for tr in iter_triples(directory, setup, triples):
        f0, f1, res, sigma, rates = tr.first, tr.second, tr.result, tr.sigma_kg_m2, tr.rates
        v_true = 0.5 * (f0.gt_velocity.astype(np.float64) + f1.gt_velocity.astype(np.float64))
        ref = eq4_reference(f0.gt_position, v_true, s, b, res.dt_s)
        has = np.isfinite(ref.u) & np.isfinite(ref.v) & np.isfinite(ref.d) & np.isfinite(
            ref.d_prime)
        cl = 0.5 * (f0.column_density_ppm_m + f1.column_density_ppm_m).astype(np.float64)
        sig_true = np.asarray(ppm_m_to_kg_m2(cl, molar_mass_kg_mol=gas.molar_mass_kg_mol,
                                             temperature_k=t_gas))
        w_t = _pick(has, res.flow, np.stack([ref.u, ref.v], axis=-1))
        d_t = _pick(has, res.disparity, ref.d)
        dd_t = _pick(has, res.disparity_change, ref.d_prime)
        s_t = np.where(has, sig_true, sigma)
        variants = {"measured": (sigma, res.flow, res.disparity, res.disparity_change),
                    "true w": (sigma, w_t, res.disparity, res.disparity_change),
                    "true d": (sigma, res.flow, d_t, res.disparity_change),
                    "true d'": (sigma, res.flow, res.disparity, dd_t),
                    "true sigma": (s_t, res.flow, res.disparity, res.disparity_change),
                    "all true": (s_t, w_t, d_t, dd_t)}
        moment = 0.5 * (f0.flux_moment_kg_s.astype(np.float64)
                        + f1.flux_moment_kg_s.astype(np.float64))
        faint = est.faint_mask(sigma, res.gas_mask)
        rows["truth"].append([true_curtain_flux(c, moment, principal_point=pp,
                                                camera_constant=s) * 1e3
                              for c in rates.curtains])
        for name, (sg, w, d, dd) in variants.items():
            vel, ok = scene_flow_velocity(w, d, dd, principal_point=pp, camera_constant=s,
                                          baseline=b, dt=res.dt_s)
            z = np.where(d > 0, s * b / np.where(d > 0, d, 1.0), 0.0)
            q = []
            for c in rates.curtains:
                f = curtain_flux(c, sg, vel, z, ok & res.valid, res.gas_mask,
                                 principal_point=pp, camera_constant=s, column_mask=faint)
                q.append(f.rate_kg_s * 1e3 if f.defined else np.nan)
            rows[name].append(q)
    width = max(len(r) for r in rows["truth"])
    return {k: np.array([r + [np.nan] * (width - len(r)) for r in v]) for k, v in rows.items()}


def main() -> None:
    args = sequence_arguments(__doc__)
    for seq in args.sequences:
        r = decompose(seq, args.triples)
        both = np.isfinite(r["truth"]) & np.all([np.isfinite(r[k]) for k in INPUTS], axis=0)
        truth = float(np.mean(r["truth"][both]))
        print(f"{seq.name}: true flux {truth:.3f} g/s; rate error with")
        print("  " + "  ".join(f"{k}: {np.mean(r[k][both]) / truth - 1:+.1%}" for k in INPUTS))
        for c in range(r["truth"].shape[1]):
            ok = both[:, c]
            if ok.any():
                t = float(np.mean(r["truth"][ok, c]))
                print(f"  curtain {c}: true {t:.3f} g/s, " + ", ".join(
                    f"{k} {np.mean(r[k][ok, c]) / t - 1:+.1%}" for k in INPUTS))


if __name__ == "__main__":
    main()
