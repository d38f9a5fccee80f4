"""The identified vehicle model: rational fits of a conditioned FRF, realized for simulation.

``fit_model(frf)`` fits a transfer function to every input/output pair of a
conditioned FRF (seed paper: ``invfreqs`` per pair; here also a common-pole
vector fit) and returns a :class:`VehicleModel`: the FRF it came from (with
coherence), the fitted pole-residue form of every pair with its fit error,
the baseline damping ``c_bar``, channel names, units and sample rate. The
model converts to an :class:`ident.sim.closedloop.LoopPlant` for closed-loop
simulation with any shocks, to a python-control state-space system in real
modal form, and to discrete time; it is saved to and loaded from one ``.npz``
file with a format version (and its reduced loop plant, so that loading it is
all a prediction pays), and exported to MATLAB ``.mat``.

Notes
-----
Every pair ``(o, i)`` is ``H(s) = sum_k r_k / (s - p_k) + d`` over its own
poles (pole-residue form: no polynomial is ever expanded in unscaled ``s``).
Conjugate poles are stored once (``Im p > 0``) with the factor 2 carried by the
realization, as in :class:`ident.sim.closedloop.ModalSystem`.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import io
import json
import logging
import multiprocessing
import os
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.data.files import atomic_path
from ident.data.channels import RIG_INPUTS
from ident.errors import FitWarning, IdentificationError, LowCoherenceWarning, ModelFileError
from ident.identify.frf import Frf

__all__ = [
    "VehicleModel",
    "fit_model",
    "identify_session",
    "load_model",
    "has_feedthrough",
    "balanced_reduce",
    "pair_noise_level",
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "PLANT_VERSION",
    "LOOP_REDUCE_RTOL",
    "RIG_REDUCE_RTOL",
]

log = logging.getLogger(__name__)

MODEL_FORMAT = "shockplan-model"
#: Version 2 stores the default loop plant (:meth:`VehicleModel.loop_plant`); version 1
#: files still load and build it on demand.
MODEL_VERSION = 2
_READABLE_VERSIONS = (1, 2)
#: Version of the loop plant's construction (:meth:`VehicleModel.loop_plant`), part of
#: :meth:`VehicleModel.plant_key`: raise it when a change to the realization or the
#: reduction changes the plant, so that plants stored in model files are rebuilt.
PLANT_VERSION = 2
#: Default fit weights (seed paper): 1 in 0.5-10 Hz, 0.5 in 10-20 Hz, 0 elsewhere.
PAPER_WEIGHTS = ((0.5, 10.0, 1.0), (10.0, 20.0, 0.5))


#: Default balanced-truncation bound of the shock part for the closed loop (see
#: :meth:`VehicleModel.loop_plant`).
LOOP_REDUCE_RTOL = 3e-2
#: Balanced-truncation bound of the rig part for the closed loop (at most ``reduce_rtol``).
RIG_REDUCE_RTOL = 1e-5

#: Order selection stops at this fit error in any case (the rounding of a good fit).
ORDER_FLOOR = 1e-3
#: Order selection stops once the fit error is within this factor of the conditioned FRF's
#: relative noise (:func:`pair_noise_level`): a higher order would fit noise (discrepancy
#: principle; the noise estimate of a smoothed FRF is approximate, hence the margin). On the
#: paper's plan with 2 % noise, the fits' errors sit at a median 1.24 times the noise level.
NOISE_FLOOR_FACTOR = 1.5
#: A pair whose fit rests on noisy data: relative noise of its conditioned FRF at least this.
NOISE_LIMITED = 0.1
#: :meth:`VehicleModel.noise_bands`: a line rests on noise where the conditioned estimate's
#: relative standard error exceeds this (a signal-to-noise amplitude ratio below 3).
NOISE_BAND_REL_ERROR = 1.0 / 3.0
#: A pair whose conditioned FRF's relative noise is at least this has a response power below
#: its noise power (``E|h|^2 = |H|^2 + sigma^2``, so ``sigma^2 / E|h|^2 >= 1/2``): it is fitted
#: as zero (the paper: "replaced by a small or zero frequency response").
ZERO_FIT_NOISE = 0.7


def has_feedthrough(output, input):
    """Whether a pair has direct feedthrough (numerator order = denominator order).

    Tire force and ride height from the wheelloader of the same corner (seed
    paper), and accelerations from the forces acting on their own body:
    chassis accelerations from the aero loads and the shock forces, a wheel's
    acceleration from its wheelloader (through the tire) and its shock.
    """
    kind, _, corner = output.rpartition("_")
    if input.startswith("wheelloader_"):
        same = input.endswith("_" + corner)
        return same and kind in ("tire_force", "ride_height", "wheel_accel")
    if kind == "chassis_accel":
        return True
    if kind == "wheel_accel" and input.startswith("dF_"):
        return input.endswith("_" + corner)
    return False


def _band_weight(f_hz, spec):
    w = np.zeros(f_hz.size)
    for lo, hi, val in spec:
        w[(f_hz >= lo) & (f_hz <= hi)] = val
    return w


@dataclass(frozen=True, eq=False)
class VehicleModel:
    """An identified vehicle model (see the module docstring).

    Attributes
    ----------
    name : str
    input_names, output_names : tuple of str
        The inputs (the session's rig inputs, then the 4 ``dF``: the 11
        ``MODEL_INPUTS`` of a 7/8-post rig, 8 for a 4-post rig without aero
        channels) and the output channels.
    poles, residues : ndarray of complex, shape (n_out, n_in, n_max)
        Per pair, padded with NaN beyond ``n_poles``; conjugate pairs stored once.
    direct : ndarray, shape (n_out, n_in)
    n_poles : ndarray of int, shape (n_out, n_in)
        Stored poles per pair (a conjugate pair counts once).
    order : ndarray of int, shape (n_out, n_in)
        Denominator order per pair (0 for a pair fitted as zero).
    fit_error : ndarray, shape (n_out, n_in)
        Relative weighted fit error per pair.
    cbar_n_s_m : ndarray, shape (4,)
        Baseline damping the model is written around [N/(m/s)].
    fs_hz : float
        Sample rate of the data [Hz].
    units : str
        Unit system of the session (for display and export).
    frf : Frf or None
        The conditioned FRF the model was fitted to (with ``H_raw`` and coherence).
    settings : dict
        How the model was made (fit method, weights, orders, session).
    noise_level : ndarray or None, shape (n_out, n_in)
        Relative noise of each pair's conditioned FRF over the fitted lines
        (:func:`pair_noise_level`): the fit error a perfect model would have.
        Pairs at or above :data:`ZERO_FIT_NOISE` are fitted as zero.
    """

    name: str
    input_names: tuple
    output_names: tuple
    poles: np.ndarray
    residues: np.ndarray
    direct: np.ndarray
    n_poles: np.ndarray
    order: np.ndarray
    fit_error: np.ndarray
    cbar_n_s_m: np.ndarray
    fs_hz: float
    units: str = "SI"
    frf: Frf | None = field(default=None, repr=False)
    settings: dict = field(default_factory=dict)
    noise_level: np.ndarray | None = None
    _plants: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def rig_inputs(self):
        """tuple of str: The rig inputs the model was identified with (``input_names`` without
        the ``dF_XX``): the 7 of ``RIG_INPUTS``, or the 4 wheelloaders of a 4-post session.

        Models saved before 4-post sessions existed have all seven. A drive
        with nonzero content on another rig input is refused in prediction
        (:func:`ident.data.drive.check_drive_inputs`).
        """
        return tuple(n for n in self.input_names if not n.startswith("dF_"))

    # -- evaluation -------------------------------------------------------------------------
    def frequency_response(self, f_hz):
        """Frequency response of the fitted model, shape (n_out, n_in, n_f)."""
        s = 2j * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
        p = np.where(np.isnan(self.poles), -1.0, self.poles)[..., None]  # padding: a dummy
        r = np.nan_to_num(self.residues)[..., None]  # stable pole with zero residue
        real = (self.poles.imag == 0)[..., None]
        terms = r / (s - p) + np.where(real, 0.0, np.conj(r) / (s - np.conj(p)))
        valid = (np.arange(self.poles.shape[-1]) < self.n_poles[..., None])[..., None]
        return np.sum(np.where(valid, terms, 0.0), axis=2) + self.direct[..., None]

    def pair_modal(self, inputs):
        """Modal system of the given input columns (union of the pairs' poles).

        Parameters
        ----------
        inputs : sequence of int
            Input indices.

        Returns
        -------
        ident.sim.closedloop.ModalSystem
            One state per distinct stored pole of each input column, driven by
            its input with B = 1 and read by every output with that pole with
            C = its residue (x2 for conjugate pairs; residues of a pole repeated
            within a pair add up).

        Notes
        -----
        A pole shared by several outputs of one input column (a common-pole
        vector fit, ``fit_model(method="vf")``, has the same poles for every
        pair) is one state: such a model's realization has ``n_in x n_poles``
        states instead of ``n_out x n_in x n_poles``. Per-pair fits
        (``invfreqs``) share no poles, so each keeps its own states, in the
        order output, pole. Only identical poles merge, so the realization is
        exact either way.
        """
        from ident.sim.closedloop import ModalSystem

        inputs = list(inputs)
        p = len(self.output_names)
        valid = np.arange(self.poles.shape[-1]) < self.n_poles[..., None]  # (p, n_in, n_max)
        lam, Bs, Cs = [], [], []
        for jj, i in enumerate(inputs):
            out, k = np.nonzero(valid[:, i])  # output-major, as stored
            if out.size == 0:
                continue
            pole, res = self.poles[out, i, k], self.residues[out, i, k]
            real = pole.imag == 0
            coef = np.where(real, res.real, 2 * res)
            uniq, first, state = np.unique(pole, return_index=True, return_inverse=True)
            order = np.argsort(first, kind="stable")  # states in order of first appearance
            rank = np.empty_like(order)
            rank[order] = np.arange(order.size)
            state = rank[state.ravel()]
            C = np.zeros((p, uniq.size), dtype=complex)
            np.add.at(C, (out, state), coef)
            b = np.zeros((uniq.size, len(inputs)), dtype=complex)
            b[:, jj] = 1.0
            lu = uniq[order]
            lam.append(np.where(lu.imag == 0, lu.real, lu))
            Bs.append(b)
            Cs.append(C)
        if not lam:
            return ModalSystem(np.zeros(0, complex), np.zeros((0, len(inputs)), complex),
                               np.zeros((p, 0), complex), self.direct[:, inputs].astype(float))
        return ModalSystem(np.concatenate(lam).astype(complex), np.concatenate(Bs),
                           np.concatenate(Cs, axis=1), self.direct[:, inputs].astype(float))

    def loop_plant(self, *, reduce_rtol=LOOP_REDUCE_RTOL):
        """The model as an :class:`ident.sim.closedloop.LoopPlant` for closed-loop simulation.

        Parameters
        ----------
        reduce_rtol : float or None
            The shock part (stepped at every sample of the shock loop) is
            reduced by balanced truncation to a relative error bound
            ``reduce_rtol`` per output (outputs scaled by their peak gain);
            ``None`` keeps the exact pole-residue realizations. The rig part,
            simulated once per drive, is reduced to the tighter
            :data:`RIG_REDUCE_RTOL` (the paper session's model: 778 modes to 68,
            and ten times less time per drive). The bound is conservative: at
            the default :data:`LOOP_REDUCE_RTOL` (0.03) the paper session's model
            keeps 11 of 520 shock modes and its predicted metrics move by at
            most 0.019 % (119 setups, track drive; a noisy generalized car's
            model: 0.018 %, 78 modes), against 0.012 % and 28 modes at 0.01.

        Notes
        -----
        The plant is built once per model and bound. :meth:`save` stores the
        default bound's plant in the model file and :func:`load_model` restores
        it, so a loaded model's plant costs nothing; the stored plant carries a
        key of the model arrays and the reduction settings
        (:meth:`plant_key`), and a plant that does not match is rebuilt.

        The plant's rig part always has the 7 columns of
        :data:`ident.data.channels.RIG_INPUTS`: those of rig inputs the model does
        not have (the aero inputs of a 4-post model) are zero, and
        ``LoopPlant.rig_inputs`` names the ones it has, so the simulator
        refuses a drive that excites the others.
        """
        from threadpoolctl import threadpool_limits

        from ident.sim.closedloop import LoopPlant, ModalSystem

        cache = self.__dict__.setdefault("_plants", {})  # built once per model and bound
        # (and for the default bound, stored in the model file: load_model fills the cache)
        if reduce_rtol in cache:
            return cache[reduce_rtol]
        n_rig = len(self.rig_inputs)
        rig = self.pair_modal(range(n_rig)).pruned()
        shock = self.pair_modal(range(n_rig, n_rig + 4)).pruned()
        if reduce_rtol is not None:
            # one BLAS thread: the dense algebra is small and threads only contend (the paper
            # session's model: 0.44 s against 7.5 s with 2 OpenBLAS threads on 2 busy cores)
            with threadpool_limits(1):
                if shock.n_states > 0:
                    shock = balanced_reduce(shock, rtol=reduce_rtol)
                if rig.n_states > 0:
                    rig = balanced_reduce(rig, rtol=min(reduce_rtol, RIG_REDUCE_RTOL))
        cols = [RIG_INPUTS.index(c) for c in self.rig_inputs]
        if cols != list(range(len(RIG_INPUTS))):  # a 4-post model: zero aero columns
            B = np.zeros((rig.n_states, len(RIG_INPUTS)), dtype=rig.B.dtype)
            D = np.zeros((rig.D.shape[0], len(RIG_INPUTS)))
            B[:, cols], D[:, cols] = rig.B, rig.D
            rig = ModalSystem(rig.lam, B, rig.C, D)
        plant = LoopPlant(rig, shock, tuple(self.output_names), self.cbar_n_s_m, name=self.name,
                          rig_inputs=self.rig_inputs)
        cache[reduce_rtol] = plant
        return plant

    def plant_key(self, reduce_rtol=LOOP_REDUCE_RTOL):
        """Fingerprint of what :meth:`loop_plant` builds from: the model's poles, residues,
        direct terms, names and c_bar, the bounds and the reduction's version.

        A loop plant stored in a model file is used only where its key matches the
        loaded model's (:func:`load_model`).

        Returns
        -------
        str
            A SHA-256 hex digest.
        """
        import hashlib

        valid = np.arange(self.poles.shape[-1]) < self.n_poles[..., None]
        h = hashlib.sha256()
        h.update(json.dumps({"plant": PLANT_VERSION, "reduce_rtol": reduce_rtol,
                             "rig_reduce_rtol": RIG_REDUCE_RTOL,
                             "gram_factor_rtol": GRAM_FACTOR_RTOL,
                             "input_names": list(self.input_names),
                             "output_names": list(self.output_names),
                             "shape": list(self.poles.shape)}).encode())
        for a, dtype in ((np.where(valid, self.poles, 0), complex),
                         (np.where(valid, self.residues, 0), complex), (self.direct, float),
                         (self.n_poles, np.int64), (self.cbar_n_s_m, float)):
            h.update(np.ascontiguousarray(a, dtype=dtype).tobytes())
        return h.hexdigest()

    def with_settings(self, settings):
        """A copy with other `settings` that keeps the loop plants built so far (they do not
        depend on the settings; :meth:`loop_plant`).

        Parameters
        ----------
        settings : dict

        Returns
        -------
        VehicleModel
        """
        new = dataclasses.replace(self, settings=settings)
        new._plants.update(self.__dict__.get("_plants", {}))
        return new

    def to_control(self, *, inputs=None):
        """A python-control ``StateSpace`` in real block-diagonal modal form.

        Parameters
        ----------
        inputs : sequence of int, optional
            Input columns (default all: 11, or 8 for a 4-post model).
        """
        import control

        idx = list(range(len(self.input_names))) if inputs is None else list(inputs)
        A, B, C, D = self.pair_modal(idx).to_real()
        return control.ss(A, B, C, D, inputs=[self.input_names[i] for i in idx],
                          outputs=list(self.output_names), name="identified")

    def discretize(self, fs_hz=None, *, method="tustin", prewarp_hz=None):
        """Discrete-time python-control system (Tustin by default, optional pre-warp).

        Parameters
        ----------
        fs_hz : float, optional
            Sample rate [Hz]; default the data's.
        method : {"tustin", "zoh", "foh"}
        prewarp_hz : float, optional
            Frequency matched exactly by the Tustin transform [Hz].
        """
        import control

        fs = self.fs_hz if fs_hz is None else float(fs_hz)
        if not fs > 0:
            raise ValueError(f"fs_hz must be positive, got {fs_hz!r}")
        m = {"tustin": "bilinear", "zoh": "zoh", "foh": "foh"}.get(method)
        if m is None:
            raise ValueError(f"method must be 'tustin', 'zoh' or 'foh', got {method!r}")
        pw = None if prewarp_hz is None else 2 * np.pi * float(prewarp_hz)
        return control.sample_system(self.to_control(), 1.0 / fs, method=m, prewarp_frequency=pw)

    def summary(self):
        """Per-pair summary table, a DataFrame.

        Columns: ``output``, ``input``, ``order``, ``fit_error``,
        ``median_coherence`` (0.5-20 Hz), ``noise_level`` (relative noise of the
        conditioned FRF, :func:`pair_noise_level`; NaN if unknown), ``status``
        (``fit``; ``zero`` for a pair fitted as zero because nothing in it is
        above the noise; ``noise-limited`` for a fit whose error is at the
        noise level and above :data:`NOISE_LIMITED`) and ``noise_bands_hz``
        (:meth:`noise_bands`, as text).
        """
        import pandas as pd

        rows = []
        coh = None
        bands = self.noise_bands() if self.frf is not None else {}
        if self.frf is not None:
            band = self.settings.get("band_hz", (0.5, 20.0))
            sel = (self.frf.f_hz >= band[0]) & (self.frf.f_hz <= band[1])
            coh = np.median(self.frf.partial_coherence[:, :, sel], axis=-1)
        zero = {tuple(z) for z in self.settings.get("zero_pairs", [])}
        for o, out in enumerate(self.output_names):
            for i, inp in enumerate(self.input_names):
                noise = float(self.noise_level[o, i]) if self.noise_level is not None else np.nan
                status = "zero" if (out, inp) in zero else (
                    "noise-limited" if noise >= NOISE_LIMITED else "fit")
                rows.append({"output": out, "input": inp, "order": int(self.order[o, i]),
                             "fit_error": float(self.fit_error[o, i]),
                             "median_coherence": float(coh[o, i]) if coh is not None else np.nan,
                             "noise_level": noise, "status": status,
                             "noise_bands_hz": " ".join(f"{a:.2f}-{b:.2f}"
                                                        for a, b in bands.get((out, inp), []))})
        return pd.DataFrame(rows)

    def noise_bands(self, *, max_rel_error=NOISE_BAND_REL_ERROR, min_width_hz=0.2,
                    floor_db=-40.0):
        """Frequency bands where a pair's conditioned estimate rests on noise.

        A line rests on noise where the conditioned FRF's relative standard
        error (:func:`ident.identify.condition.conditioned_standard_error`) exceeds
        `max_rel_error` while the response is within `floor_db` of the pair's
        peak (below that the response is too small to matter, as the paper
        argues); lines replaced by residual fits count when their raw estimate
        did. Bands narrower than `min_width_hz` are dropped.

        Returns
        -------
        dict
            ``(output, input) -> [(f_lo_hz, f_hi_hz), ...]`` for the pairs that
            have such bands, within the model's fit band.
        """
        from ident.identify.condition import conditioned_standard_error

        if self.frf is None:
            return {}
        frf = self.frf
        f = frf.f_hz
        lo, hi = self.settings.get("band_hz", (0.5, 20.0))
        sel = np.flatnonzero((f >= lo) & (f <= hi))
        sig = conditioned_standard_error(frf)[:, :, sel]
        mag = np.abs(frf.H[:, :, sel])
        peak = mag.max(axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(mag > 0, sig / mag, np.inf)
        bad = (rel > max_rel_error) & (mag >= peak * 10 ** (floor_db / 20))
        df = f[1] - f[0]
        out = {}
        for o, i in zip(*np.nonzero(bad.any(axis=-1))):
            idx = np.flatnonzero(bad[o, i])
            runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
            spans = [(float(f[sel[r[0]]]), float(f[sel[r[-1]]])) for r in runs
                     if (r[-1] - r[0] + 1) * df >= min_width_hz]
            if spans:
                out[(self.output_names[o], self.input_names[i])] = spans
        return out

    # -- files -------------------------------------------------------------------------------
    def save(self, path, *, overwrite=False, with_plant=True):
        """Save to one ``.npz`` file (atomic), with the format name and version.

        Parameters
        ----------
        path : str or Path
        overwrite : bool
            Replace an existing file.
        with_plant : bool
            Store the default loop plant (:meth:`loop_plant` at
            :data:`LOOP_REDUCE_RTOL`, built now if it is not yet), so that loading
            the file gives it at no cost. The paper session's model: under 0.1 MB.

        Returns
        -------
        Path

        Raises
        ------
        FileExistsError
            If `path` exists and `overwrite` is false.
        """
        meta = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "name": self.name,
                "input_names": list(self.input_names), "output_names": list(self.output_names),
                "fs_hz": self.fs_hz, "units": self.units, "settings": _jsonable(self.settings),
                "has_frf": self.frf is not None}
        arrays = {"poles": self.poles, "residues": self.residues, "direct": self.direct,
                  "n_poles": self.n_poles, "order": self.order, "fit_error": self.fit_error,
                  "cbar_n_s_m": self.cbar_n_s_m}
        if self.noise_level is not None:
            arrays["noise_level"] = self.noise_level
        if self.frf is not None:
            fr = self.frf
            arrays.update({"frf_f_hz": fr.f_hz, "frf_H": fr.H, "frf_multiple_coherence":
                           fr.multiple_coherence, "frf_partial_coherence": fr.partial_coherence,
                           "frf_input_condition": fr.input_condition,
                           "frf_independent_fraction": fr.independent_fraction,
                           "frf_flagged": fr.flagged})
            if fr.H_raw is not None:
                arrays["frf_H_raw"] = fr.H_raw
            if fr.replaced is not None:
                arrays["frf_replaced"] = fr.replaced
            if fr.sigma is not None:
                arrays["frf_sigma"] = fr.sigma
            meta["frf"] = {"input_names": list(fr.input_names),
                           "output_names": list(fr.output_names), "n_averages": fr.n_averages,
                           "settings": _jsonable(fr.settings)}
        if with_plant:
            plant = self.loop_plant()
            meta["loop_plant"] = {"reduce_rtol": LOOP_REDUCE_RTOL, "key": self.plant_key(),
                                  "output_names": list(plant.output_names),
                                  "rig_inputs": list(plant.rig_inputs)}
            arrays["plant_cbar_n_s_m"] = plant.cbar_n_s_m
            for part in ("rig", "shock"):
                ms = getattr(plant, part)
                arrays.update({f"plant_{part}_{k}": getattr(ms, k) for k in ("lam", "B", "C", "D")})
        buf = io.BytesIO()
        # stored, not deflated: the FRF's noisy complex lines compress by 15 % only, at 1.2 s
        # of a 1.3 s save (paper session: 31.8 MB stored against 27.1 MB deflated)
        np.savez(buf, meta=np.array(json.dumps(meta)), **arrays)
        path = Path(path)
        with atomic_path(path, overwrite=overwrite) as tmp:
            tmp.write_bytes(buf.getvalue())
        return path

    def export_mat(self, path, *, overwrite=False):
        """Export to a MATLAB ``.mat`` file: real modal A, B, C, D, names, FRF and coherence."""
        from scipy.io import savemat

        A, B, C, D = self.pair_modal(range(len(self.input_names))).to_real()
        data = {"A": A, "B": B, "C": C, "D": D, "input_names": np.array(self.input_names, dtype=object),
                "output_names": np.array(self.output_names, dtype=object),
                "cbar_n_s_m": self.cbar_n_s_m, "fs_hz": self.fs_hz, "fit_error": self.fit_error,
                "order": self.order, "units_note": "SI inside: N, m, m/s, N*m"}
        if self.frf is not None:
            data.update({"f_hz": self.frf.f_hz, "H": self.frf.H,
                         "partial_coherence": self.frf.partial_coherence,
                         "multiple_coherence": self.frf.multiple_coherence})
        path = Path(path)
        with atomic_path(path, overwrite=overwrite) as tmp:
            with open(tmp, "wb") as fh:
                savemat(fh, data, do_compression=True)
        return path


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    return obj


def load_model(path):
    """Load a :class:`VehicleModel` saved by :meth:`VehicleModel.save`.

    Raises
    ------
    ModelFileError
        If the file is missing, not a shockplan model, corrupt, or of another
        format version.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{path}: model file not found; run 'shockplan identify' to make one")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"PK\x03\x04":  # np.load would try other formats (pickle) and advise on them
        what = "empty" if not magic else "not a .npz archive"
        raise ModelFileError(f"{path}: not a shockplan model file ({what}); the file is corrupt "
                             "or of another kind; re-run 'shockplan identify'")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(str(data.pop("meta")))
    except ValueError as exc:
        why = ("holds Python objects, which shockplan never writes" if "allow_pickle" in str(exc)
               else str(exc))
        raise ModelFileError(f"{path}: not a shockplan model file ({why}); the file is "
                             "corrupt or of another kind; re-run 'shockplan identify'") from None
    except (OSError, KeyError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError,
            UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: not a readable shockplan model file ({type(exc).__name__}: "
                             f"{exc}); the file is corrupt or of another kind; re-run "
                             "'shockplan identify'") from None
    if not isinstance(meta, dict):
        raise ModelFileError(f"{path}: not a shockplan model file (its 'meta' is not a table); "
                             "re-run 'shockplan identify'")
    if meta.get("format") != MODEL_FORMAT:
        raise ModelFileError(f"{path}: format {meta.get('format')!r} is not {MODEL_FORMAT!r}")
    if meta.get("version") not in _READABLE_VERSIONS:
        raise ModelFileError(f"{path}: model file version {meta.get('version')!r}; this shockplan "
                             f"reads versions {', '.join(map(str, _READABLE_VERSIONS))}; "
                             "re-identify with this version")
    try:
        frf = None
        if meta.get("has_frf"):
            fm = meta["frf"]
            frf = Frf(f_hz=data["frf_f_hz"], H=data["frf_H"], input_names=tuple(fm["input_names"]),
                      output_names=tuple(fm["output_names"]),
                      multiple_coherence=data["frf_multiple_coherence"],
                      partial_coherence=data["frf_partial_coherence"],
                      input_condition=data["frf_input_condition"],
                      independent_fraction=data["frf_independent_fraction"],
                      flagged=data["frf_flagged"], n_averages=int(fm["n_averages"]),
                      cbar_n_s_m=data["cbar_n_s_m"], fs_hz=float(meta["fs_hz"]),
                      settings=fm["settings"], H_raw=data.get("frf_H_raw"),
                      replaced=data.get("frf_replaced"), sigma=data.get("frf_sigma"))
        model = VehicleModel(name=meta["name"], input_names=tuple(meta["input_names"]),
                             output_names=tuple(meta["output_names"]), poles=data["poles"],
                             residues=data["residues"], direct=data["direct"],
                             n_poles=data["n_poles"], order=data["order"],
                             fit_error=data["fit_error"], cbar_n_s_m=data["cbar_n_s_m"],
                             fs_hz=float(meta["fs_hz"]), units=meta.get("units", "SI"), frf=frf,
                             settings=meta.get("settings", {}),
                             noise_level=data.get("noise_level"))
        if "loop_plant" in meta:
            _restore_plant(model, meta["loop_plant"], data, path)
        return model
    except KeyError as exc:
        raise ModelFileError(f"{path}: model file lacks {exc}; the file is corrupt; re-run "
                             "'shockplan identify'") from None
    except (TypeError, ValueError, AttributeError, IndexError) as exc:
        raise ModelFileError(f"{path}: model file is corrupt ({type(exc).__name__}: {exc}); "
                             "re-run 'shockplan identify'") from None


def _restore_plant(model, pm, data, path):
    """Put a model file's stored loop plant into the model's cache, if it is the model's.

    A plant whose key (:meth:`VehicleModel.plant_key`) differs from the loaded model's
    (another shockplan's reduction, or arrays changed after it was stored) is left out
    and rebuilt on demand.
    """
    from ident.sim.closedloop import LoopPlant, ModalSystem

    rtol = pm["reduce_rtol"]
    if pm.get("key") != model.plant_key(rtol):
        log.info("%s: the stored loop plant does not match the model (another version of "
                 "the reduction, or changed arrays); it is rebuilt when needed", path)
        return
    parts = {part: ModalSystem(*(data[f"plant_{part}_{k}"] for k in ("lam", "B", "C", "D")))
             for part in ("rig", "shock")}
    model._plants[rtol] = LoopPlant(parts["rig"], parts["shock"], tuple(pm["output_names"]),
                                    data["plant_cbar_n_s_m"], name=model.name,
                                    rig_inputs=tuple(pm["rig_inputs"]))


def _mode_gram(lam, X):
    """``int_0^inf g(t) g(t)^T dt`` of the real coordinates of modes ``z_i(t) = X_i e^(lam_i t)``.

    Parameters
    ----------
    lam : ndarray of complex, shape (n,)
        Stable poles [rad/s] (real modes with ``Im lam == 0`` and real rows of `X`).
    X : ndarray of complex, shape (n, k)
        One row per mode.

    Returns
    -------
    ndarray, shape (n, 2, n, 2)
        ``G[i, a, j, b]`` pairs coordinate ``a`` of mode ``i`` with coordinate ``b`` of mode
        ``j`` (0: ``Re z``, 1: ``Im z``), summed over the columns of `X`.

    Notes
    -----
    With ``M1 = int z z^H = -(X X^H) / (lam_i + conj lam_j)`` and
    ``M2 = int z z^T = -(X X^T) / (lam_i + lam_j)`` (the ``int`` over ``t`` and summed
    over the columns of `X`): ``int Re z Re z^T = Re(M1 + M2) / 2``,
    ``int Im z Im z^T = Re(M1 - M2) / 2``, ``int Re z Im z^T = Im(M2 - M1) / 2`` and
    ``int Im z Re z^T = Im(M1 + M2) / 2``. A real mode (real pole and row) has
    ``Im z = 0``, and its ``Re`` entries come out right from the same formulas.
    """
    m1 = -(X @ np.conj(X).T) / (lam[:, None] + np.conj(lam)[None, :])
    m2 = -(X @ X.T) / (lam[:, None] + lam[None, :])
    n = lam.size
    G = np.empty((n, 2, n, 2))
    G[:, 0, :, 0] = (m1.real + m2.real) / 2
    G[:, 1, :, 1] = (m1.real - m2.real) / 2
    G[:, 0, :, 1] = (m2.imag - m1.imag) / 2
    G[:, 1, :, 0] = (m2.imag + m1.imag) / 2
    return G


def _modal_gramians(modal, Bs, Cs):
    """Controllability and observability gramians of a stable modal system, real coordinates.

    Closed form from the modal form, O(n^2) instead of the O(n^3) of a Lyapunov solver:
    in the coordinates of :meth:`ModalSystem.to_real` (``[Re x, Im x]`` per complex mode,
    ``x`` per real mode) ``P = int x x^T`` for impulses ``x_i = B_i e^(lam_i t)``, and ``Q``
    the same for the output trajectories of unit initial states: ``Re(c_i e^(lam_i t))``
    from ``Re x_i`` and ``-Im(c_i e^(lam_i t))`` from ``Im x_i`` (:func:`_mode_gram`).

    Parameters
    ----------
    modal : ModalSystem
        Stable; its poles.
    Bs : ndarray of complex, shape (n, m)
    Cs : ndarray of complex, shape (p, n)

    Returns
    -------
    P, Q : ndarray, shape (n_real, n_real)
        ``n_real`` counts a complex mode twice.
    """
    lam = np.asarray(modal.lam, dtype=complex)
    real = lam.imag == 0
    # real modes: real coefficients, as to_real() takes them
    Bs = np.where(real[:, None], np.real(Bs), Bs)
    Cs = np.where(real[None, :], np.real(Cs), Cs)
    keep = np.stack([np.ones(lam.size, bool), ~real], axis=1).ravel()  # [Re, Im] per mode
    n2 = 2 * lam.size
    P = _mode_gram(lam, Bs).reshape(n2, n2)[np.ix_(keep, keep)]
    G = _mode_gram(lam, Cs.T)
    G[:, 0, :, 1] *= -1  # the Im coordinate reads -Im(c x)
    G[:, 1, :, 0] *= -1
    Q = G.reshape(n2, n2)[np.ix_(keep, keep)]
    return P, Q


#: Pivoted-Cholesky stopping tolerance of the gramian factors (:func:`_gram_factor`),
#: relative to the largest diagonal entry: the rounding level of the gramians themselves.
GRAM_FACTOR_RTOL = float(np.finfo(float).eps)


def _gram_factor(M):
    """A low-rank factor ``L`` with ``M ~= L L^T`` of a symmetric positive semidefinite gramian.

    Pivoted Cholesky (LAPACK ``dpstrf``), stopped where the largest remaining diagonal
    entry falls below :data:`GRAM_FACTOR_RTOL` times the largest: the remainder is
    positive semidefinite, so its norm is at most its trace, at the gramians' rounding
    level. The gramians of an identified model have low numerical rank (the paper
    session's rig part: about 350 and 590 of 1534), so this costs ``O(n^2 r)`` against
    the ``O(n^3)`` of an eigendecomposition (a tenth of the time), and the Hankel
    singular values then come from an ``r_q x r_p`` product.

    Parameters
    ----------
    M : ndarray, shape (n, n)
        Only the lower triangle is read.

    Returns
    -------
    ndarray, shape (n, r)
        ``r = 0`` for a zero matrix.
    """
    from scipy.linalg import lapack

    n = M.shape[0]
    top = float(np.max(np.diag(M), initial=0.0))
    if not top > 0:
        return np.zeros((n, 0))
    c, piv, rank, info = lapack.dpstrf(M, lower=1, tol=GRAM_FACTOR_RTOL * top)
    if info < 0:
        raise ValueError(f"dpstrf: argument {-info} is invalid")
    L = np.zeros((n, rank))
    L[piv - 1] = np.tril(c[:, :rank])
    return L


def balanced_reduce(modal, *, rtol=1e-4):
    """Balanced truncation of a stable modal system to a relative error bound.

    Outputs and inputs are scaled by their peak gains first, so the bound
    ``2 * sum(truncated Hankel singular values) <= rtol * largest`` is relative
    per channel. The gramians come in closed form from the modal form
    (:func:`_modal_gramians`), their square-root factors from a pivoted Cholesky
    stopped at their rounding level (:func:`_gram_factor`: low rank, so the
    singular value decomposition is of an ``r_q x r_p`` matrix). Returns a
    :class:`ident.sim.closedloop.ModalSystem`.
    """
    from ident.sim.closedloop import ModalSystem, modal_form

    if np.any(modal.lam.real >= 0):
        raise IdentificationError("balanced_reduce needs a stable system; reflect unstable poles first")
    f = np.geomspace(0.3, 30, 60)
    H = modal.frequency_response(f)
    so = np.maximum(np.abs(H).max(axis=(1, 2)), 1e-300)  # per output
    si = np.maximum(np.abs(H / so[:, None, None]).max(axis=(0, 2)), 1e-300)  # per input
    Bsc = modal.B * si[None, :]
    Csc = modal.C / so[:, None]
    P, Q = _modal_gramians(modal, Bsc, Csc)
    scaled = type(modal)(modal.lam, Bsc, Csc, modal.D)
    A, Bs, Cs, _ = scaled.to_real()

    Lp, Lq = _gram_factor(P), _gram_factor(Q)
    if Lp.shape[1] == 0 or Lq.shape[1] == 0:  # nothing reaches the outputs
        return ModalSystem(np.zeros(0, complex), np.zeros((0, modal.B.shape[1]), complex),
                           np.zeros((modal.C.shape[0], 0), complex), modal.D)
    U, sv, Vt = np.linalg.svd(Lq.T @ Lp, full_matrices=False)
    tail = np.concatenate([2 * np.cumsum(sv[::-1])[::-1], [0.0]])  # tail[k] = 2 sum(sv[k:])
    r = int(np.argmax(tail <= rtol * sv[0]))
    r = max(1, min(r, sv.size))
    s = 1.0 / np.sqrt(sv[:r])
    Tm = (Lp @ Vt[:r].T) * s[None, :]
    Tim = (U[:, :r].T @ Lq.T) * s[:, None]
    Ar, Br, Cr = Tim @ A @ Tm, (Tim @ Bs) / si[None, :], so[:, None] * (Cs @ Tm)
    red = modal_form(Ar, Br, Cr, modal.D)
    log.info("balanced truncation: %d -> %d states (bound %.2g)", A.shape[0], r, tail[r] / sv[0])
    return red


# ----------------------------------------------------------------------------------------------
# fitting
# ----------------------------------------------------------------------------------------------

def fit_model(frf, *, method="invfreqs", orders="auto", weighting="paper", band_hz=(0.5, 20.0),
              max_order=10, n_poles_vf=None, df_fit_hz=0.1, name=None, units="SI", n_jobs=None):
    """Fit a rational model to every input/output pair of a conditioned FRF.

    Parameters
    ----------
    frf : Frf
        Conditioned FRF (:func:`ident.identify.condition.condition_frf`).
    method : {"invfreqs", "vf"}
        ``invfreqs``: a transfer function per pair (output-error Gauss-Newton
        from a Levi / Sanathanan-Koerner start, as MATLAB's ``invfreqs``).
        ``vf``: vector fitting with one set of poles common to all pairs.
    orders : "auto", int or dict
        Denominator order per pair: ``"auto"`` picks the smallest order 2..
        `max_order` whose fit error stops improving; an int for all pairs; a
        dict ``{(output, input): order}`` overriding ``auto``.
    weighting : {"paper", "coherence", "relative"}
        ``paper``: 1 in 0.5-10 Hz, 0.5 in 10-20 Hz on the absolute error (as
        ``invfreqs``). ``coherence``: the paper weights times the partial
        coherence. ``relative``: the paper weights on the relative error, with
        the magnitude floored at 40 dB below the pair's peak (low-magnitude
        regions then count as much as high ones down to that floor).
    band_hz : (float, float)
        Frequencies used by the fit [Hz].
    n_poles_vf : int, optional
        Number of poles for ``vf`` (default: the smallest even number whose fits
        reach the data's noise, plus ``VF_ORDER_MARGIN``, up to ``2 * max_order``;
        see ``_fit_vf``).
    df_fit_hz : float
        Frequency spacing of the points used by the fit [Hz]: the conditioned
        FRF is smooth over its 0.6 Hz smoothing width, so thinning the Welch
        grid to about 0.1 Hz loses nothing and makes the fits 4x cheaper.
    n_jobs : int, optional
        Processes for the per-pair fits (``invfreqs``); default every core.
        The model is the same whatever the number.

    Returns
    -------
    VehicleModel
    """
    from ident.identify import fit as fitmod

    if not isinstance(frf, Frf):
        raise TypeError(f"fit_model needs an Frf, got {type(frf).__name__}")
    if method not in ("invfreqs", "vf"):
        raise ValueError(f"method must be 'invfreqs' or 'vf', got {method!r}")
    if weighting not in ("paper", "coherence", "relative"):
        raise ValueError(f"weighting must be 'paper', 'coherence' or 'relative', got {weighting!r}")
    f = frf.f_hz
    step = max(1, int(round(df_fit_hz / (f[1] - f[0]))))
    sel = np.flatnonzero((f >= band_hz[0]) & (f <= band_hz[1]))[::step]
    fb = f[sel]
    w0 = _band_weight(fb, [(max(lo, band_hz[0]), min(hi, band_hz[1]), v) for lo, hi, v in PAPER_WEIGHTS])
    if not np.any(w0 > 0):
        w0 = np.ones(fb.size)
    p, m = len(frf.output_names), len(frf.input_names)
    Hb = frf.H[:, :, sel]
    W = np.broadcast_to(w0, Hb.shape).copy()
    if weighting == "coherence":
        W *= np.clip(frf.partial_coherence[:, :, sel], 0, 1)
    elif weighting == "relative":
        peak = np.abs(np.where(W > 0, Hb, 0)).max(axis=-1, keepdims=True)
        W /= np.maximum(np.abs(Hb), 0.01 * np.maximum(peak, 1e-300)) ** 2
    settings = {"method": method, "orders": orders if isinstance(orders, (str, int)) else "dict",
                "weighting": weighting, "band_hz": tuple(band_hz), "max_order": max_order,
                "df_fit_hz": float(fb[1] - fb[0]) if fb.size > 1 else None}
    nmax = 2 * max_order
    poles = np.full((p, m, nmax), np.nan, dtype=complex)
    residues = np.full((p, m, nmax), np.nan, dtype=complex)
    direct = np.zeros((p, m))
    n_poles = np.zeros((p, m), dtype=int)
    order = np.zeros((p, m), dtype=int)
    err = np.zeros((p, m))
    from threadpoolctl import threadpool_limits

    f_max = 10.0 * band_hz[1]
    f_min = band_hz[0] / 5.0
    n_regularized = 0
    noise = pair_noise_level(frf, sel, W)
    zero = noise >= ZERO_FIT_NOISE
    n_short = 0
    if method == "invfreqs":
        tasks = []
        for o in range(p):
            for i in range(m):
                key = (frf.output_names[o], frf.input_names[i])
                if isinstance(orders, dict) and key in orders:
                    order_i = int(orders[key])
                elif isinstance(orders, (int, np.integer)) and not isinstance(orders, bool):
                    order_i = int(orders)
                else:
                    order_i = None  # auto
                if zero[o, i] and order_i is None:
                    # nothing above the noise: a fit would make up dynamics (order 0)
                    err[o, i] = 1.0
                    continue
                tasks.append((o, i, has_feedthrough(*key), order_i,
                              max(ORDER_FLOOR, NOISE_FLOOR_FACTOR * noise[o, i]),
                              _is_derivative(key[0])))
        common = (fb, Hb, W, max_order, f_max, f_min)
        results = _map_pairs(_fit_pairs, common, tasks, n_jobs)
        messages = []
        for (o, i, *_), (pk, rk, dk, n_den, e, changed, msgs) in zip(tasks, results):
            n_regularized += changed
            _store(pk, rk, dk, o, i, poles, residues, direct, n_poles)
            order[o, i] = n_den
            err[o, i] = e
            if msgs:
                n_short += 1
                messages += msgs
        if messages:
            warnings.warn(f"{n_short} pair fits stay above their data's noise level and needed "
                          f"attention (e.g. {messages[0]}); see the model summary's fit errors "
                          "against 'noise_level'", FitWarning, stacklevel=2)
    else:
        with threadpool_limits(1):
            vf = _fit_vf(fitmod, fb, Hb, W, frf, n_poles_vf, max_order)
        settings["n_poles_vf"] = int(len(vf.poles))
        for o in range(p):
            for i in range(m):
                ft = has_feedthrough(frf.output_names[o], frf.input_names[i])
                pk, rk, dk, changed = _regularize(vf.poles, fb, Hb[o, i], W[o, i], ft, f_max,
                                                  f_min_hz=f_min,
                                                  zero_dc=_is_derivative(frf.output_names[o]))
                n_regularized += changed
                _store(pk, rk, dk, o, i, poles, residues, direct, n_poles)
                order[o, i] = len(vf.poles)
                err[o, i] = _fit_error(pk, rk, dk, fb, Hb[o, i], W[o, i])
    settings["zeta_min"] = ZETA_MIN
    settings["pole_f_max_hz"] = f_max
    settings["pole_f_min_hz"] = f_min
    settings["n_pairs_regularized"] = int(n_regularized)
    settings["noise_floor_factor"] = NOISE_FLOOR_FACTOR
    settings["zero_fit_noise"] = ZERO_FIT_NOISE
    zeroed = [[frf.output_names[o], frf.input_names[i]] for o, i in zip(*np.nonzero(zero))
              if method == "invfreqs" and not (isinstance(orders, dict) and
                                               (frf.output_names[o], frf.input_names[i]) in orders)]
    settings["zero_pairs"] = zeroed
    if zeroed:
        warnings.warn(f"{len(zeroed)} pair(s) have no response above the noise (e.g. "
                      f"{zeroed[0][0]} from {zeroed[0][1]}: relative noise of the conditioned "
                      f"FRF >= {ZERO_FIT_NOISE}); fitted as zero (order 0) instead of making up "
                      "dynamics; see the model summary's 'status'", LowCoherenceWarning,
                      stacklevel=2)
    keep = max(1, int(n_poles.max()))
    return VehicleModel(name=name or "identified model", input_names=tuple(frf.input_names),
                        output_names=tuple(frf.output_names), poles=poles[:, :, :keep],
                        residues=residues[:, :, :keep], direct=direct, n_poles=n_poles,
                        order=order, fit_error=err, cbar_n_s_m=np.asarray(frf.cbar_n_s_m, float),
                        fs_hz=frf.fs_hz, units=units, frf=frf, settings=settings,
                        noise_level=noise)


def pair_noise_level(frf, sel=None, weight=None):
    """Relative noise of each pair's conditioned FRF over the fitted lines.

    ``sqrt(sum w sigma^2 / sum w |H|^2)`` with ``sigma`` the conditioned
    estimate's standard error (:func:`ident.identify.condition.conditioned_standard_error`)
    and ``w`` the fit weights: the fit error a fit to the noise-free response
    would have against these data.

    Parameters
    ----------
    frf : Frf
    sel : ndarray of int, optional
        Frequency indices (default all).
    weight : ndarray, shape (n_out, n_in, len(sel)), optional
        Default 1.

    Returns
    -------
    ndarray, shape (n_out, n_in)
        0 for noise-free data; ``inf`` where the coherence is 0 throughout.
    """
    from ident.identify.condition import conditioned_standard_error

    sel = np.arange(frf.f_hz.size) if sel is None else np.asarray(sel)
    sig = conditioned_standard_error(frf)[:, :, sel]
    H = frf.H[:, :, sel]
    w = np.ones(H.shape) if weight is None else np.broadcast_to(weight, H.shape)
    with np.errstate(invalid="ignore", over="ignore"):
        num = np.sum(w * np.where(np.isfinite(sig), sig, np.abs(H)) ** 2, axis=-1)
        den = np.sum(w * np.abs(H) ** 2, axis=-1)
        return np.where(den > 0, np.sqrt(num / np.where(den > 0, den, 1.0)), np.inf)


#: Smallest damping ratio kept for an identified pole: car modes on a rig are damped well
#: above 2 %; lighter poles in a fit are artifacts of noisy FRF regions (a pole and a zero
#: nearly cancelling) that would ring in a closed-loop simulation.
ZETA_MIN = 0.02


#: Output kinds that are time derivatives of a displacement: a static input gives them zero
#: response, so their fits are constrained to zero DC gain.
DERIVATIVE_KINDS = ("shock_velocity", "chassis_accel", "wheel_accel")


def _regularize(pl, fb, h, w, feedthrough, f_max_hz, zeta_min=ZETA_MIN, f_min_hz=None,
                zero_dc=False):
    """Bound a fit's poles and refit residues.

    Damping >= zeta_min, ``2 pi f_min <= |p| <= 2 pi f_max``: outside the fitted
    band a per-pair fit is unconstrained, and a very slow pole (time constants
    of minutes) or a very fast one would dominate the model's out-of-band
    behaviour (its gramians, the closed loop's drift) while adding nothing in
    band.

    Parameters
    ----------
    pl : ndarray of complex
        The fit's poles (conjugates included or not; only Im >= 0 are used).
    fb, h, w : ndarray
        Frequencies [Hz], data and weights of the fit.
    feedthrough : bool
        Whether the pair has a direct term.
    zero_dc : bool
        Constrain the DC gain to zero (outputs that are derivatives: the fit
        band starts at 0.5 Hz, and a road drive's large low-frequency
        displacement would otherwise meet a spurious static gain).

    Returns
    -------
    poles, residues : ndarray of complex (one per pair or real pole), d : float, changed : bool
    """
    pl = np.asarray(pl, dtype=complex)
    tol = 1e-9 * np.maximum(np.abs(pl), 1e-300)
    pl = pl[(pl.imag > tol) | (np.abs(pl.imag) <= tol)]
    real = np.abs(pl.imag) <= 1e-9 * np.maximum(np.abs(pl), 1e-300)
    lo = 0.0 if f_min_hz is None else 2 * np.pi * f_min_hz
    mag = np.clip(np.abs(pl), lo, 2 * np.pi * f_max_hz)
    zeta = np.where(real, 1.0, np.clip(-pl.real / np.maximum(np.abs(pl), 1e-300), zeta_min, 1.0))
    new = np.where(real, -np.clip(np.abs(pl.real), lo, 2 * np.pi * f_max_hz),
                   -zeta * mag + 1j * mag * np.sqrt(np.maximum(1 - zeta**2, 0.0)))
    changed = bool(np.any(np.abs(new - pl) > 1e-9 * np.abs(pl)))
    s = 2j * np.pi * fb
    cols = []
    for p, rl in zip(new, real):
        if rl:
            cols.append(1.0 / (s - p.real))
        else:
            cols.append(1.0 / (s - p) + 1.0 / (s - np.conj(p)))
            cols.append(1j / (s - p) - 1j / (s - np.conj(p)))
    if feedthrough:
        cols.append(np.ones_like(s))
    X = np.column_stack(cols)
    sw = np.sqrt(np.maximum(w, 0))
    A = np.vstack([(X * sw[:, None]).real, (X * sw[:, None]).imag])
    b = np.concatenate([(h * sw).real, (h * sw).imag])
    if zero_dc:
        row = []
        for p, rl in zip(new, real):
            if rl:
                row.append(-1.0 / p.real)
            else:
                row += [np.real(-1.0 / p - 1.0 / np.conj(p)), np.real(-1j / p + 1j / np.conj(p))]
        if feedthrough:
            row.append(1.0)
        row = np.array(row)
        big = 1e8 * max(np.abs(A).max(), 1e-300) / max(np.abs(row).max(), 1e-300)
        A = np.vstack([A, big * row])
        b = np.concatenate([b, [0.0]])
        changed = True
    scale = np.maximum(np.abs(A).max(axis=0), 1e-300)
    coef = np.linalg.lstsq(A / scale, b, rcond=None)[0] / scale
    res, k = [], 0
    for rl in real:
        if rl:
            res.append(complex(coef[k]))
            k += 1
        else:
            res.append(coef[k] + 1j * coef[k + 1])
            k += 2
    d = float(coef[k]) if feedthrough else 0.0
    return new, np.array(res, dtype=complex), d, changed


def _store(pole_list, res_list, d, o, i, poles, residues, direct, n_poles):
    """Keep one pole of each conjugate pair (Im > 0) and the real poles."""
    pl = np.asarray(pole_list, dtype=complex)
    rl = np.asarray(res_list, dtype=complex)
    tol = 1e-9 * np.maximum(np.abs(pl), 1e-300)
    keep = (pl.imag > tol) | (np.abs(pl.imag) <= tol)
    pk, rk = pl[keep], rl[keep]
    real = np.abs(pk.imag) <= tol[keep]
    pk = np.where(real, pk.real, pk)
    rk = np.where(real, rk.real, rk)
    k = pk.size
    poles[o, i, :k] = pk
    residues[o, i, :k] = rk
    direct[o, i] = float(np.real(d))
    n_poles[o, i] = k


def _is_derivative(output):
    return output.rpartition("_")[0] in DERIVATIVE_KINDS


def _fit_error(pk, rk, d, fb, h, w):
    """Relative weighted error of a pole-residue fit (as TfFit.fit_error)."""
    s = 2j * np.pi * fb[:, None]
    real = (pk.imag == 0)[None, :]
    terms = rk / (s - pk) + np.where(real, 0.0, np.conj(rk) / (s - np.conj(pk)))
    fit = terms.sum(axis=1) + d
    return float(np.sqrt(np.sum(w * np.abs(h - fit) ** 2) / max(np.sum(w * np.abs(h) ** 2), 1e-300)))


def _fit_pairs(common, tasks):
    """Fit a batch of pairs (a worker of :func:`fit_model`).

    Parameters
    ----------
    common : tuple
        ``(fb, Hb, W, max_order, f_max, f_min)``.
    tasks : list of tuple
        ``(o, i, feedthrough, order or None for auto, floor, zero_dc)``.

    Returns
    -------
    list of tuple
        Per task ``(poles, residues, direct, order, fit_error, regularized, messages)``;
        ``messages`` are the fit's warnings, kept only where the fit error stays above
        `floor` (a fit within its data's noise needs no word about how it got there).
    """
    from threadpoolctl import threadpool_limits

    from ident.identify import fit as fitmod

    fb, Hb, W, max_order, f_max, f_min = common
    out = []
    with threadpool_limits(1):  # single-threaded BLAS: many small problems (3-4x faster)
        for o, i, ft, n_fixed, floor, zero_dc in tasks:
            rel = 0 if ft else -1
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", FitWarning)
                if n_fixed is None:
                    # choose the order with the linear (Sanathanan-Koerner) fits, stopping where
                    # the fit reaches the data's noise, then refine that order alone with the
                    # output-error Gauss-Newton
                    sk, _ = fitmod.select_order(fb, Hb[o, i], weight=W[o, i],
                                                orders=range(2, max_order + 1), relative_num=rel,
                                                method="sk", floor=floor)
                    n = len(sk.poles)
                else:
                    n = n_fixed
                tf = fitmod.fit_tf(fb, Hb[o, i], weight=W[o, i], n_den=n, n_num=n + rel)
            pk, rk, dk, changed = _regularize(tf.poles, fb, Hb[o, i], W[o, i], ft, f_max,
                                              f_min_hz=f_min, zero_dc=zero_dc)
            e = _fit_error(pk, rk, dk, fb, Hb[o, i], W[o, i])
            msgs = [str(w.message) for w in caught if issubclass(w.category, FitWarning)]
            out.append((pk, rk, dk, len(tf.poles), e, changed, msgs if e > floor else []))
    return out


def _map_pairs(func, common, tasks, n_jobs):
    """``func(common, batch)`` over batches of `tasks`, on up to `n_jobs` processes.

    Results come back in the order of `tasks`, and each pair's fit is deterministic, so the
    model does not depend on the number of processes. Workers are forked (POSIX; elsewhere the
    fits run in this process): a fork server or spawned workers would re-run an unguarded
    script's top level. The workers only run numpy and scipy with one BLAS thread, so the
    parent's thread pools (numba's OpenMP, BLAS) are never used in a child.
    """
    n = (os.cpu_count() or 1) if n_jobs is None else int(n_jobs)
    n = max(1, min(n, len(tasks)))
    if n == 1 or "fork" not in multiprocessing.get_all_start_methods():
        return func(common, tasks)
    size = max(1, -(-len(tasks) // (4 * n)))  # about 4 batches per process
    batches = [tasks[k:k + size] for k in range(0, len(tasks), size)]
    ctx = multiprocessing.get_context("fork")
    with concurrent.futures.ProcessPoolExecutor(max_workers=n, mp_context=ctx) as pool:
        parts = list(pool.map(func, [common] * len(batches), batches))
    return [r for part in parts for r in part]


#: ``vf``: poles added to the order at which the common-pole fit first reaches its data's noise
#: (:func:`_fit_vf`). On a noisy car with a flexible chassis (8 modes, 2 % noise) the noise is
#: reached at 12 poles, where two of the four heavily damped hop modes share a pole pair: the fit
#: is as close to the data, but the model closed around other shocks is not (closed-loop metric
#: error median/max 0.13 %/0.57 % at 12 poles, 0.09 %/0.48 % at 16, invfreqs 0.09 %/0.44 %).
VF_ORDER_MARGIN = 4


def _fit_vf(fitmod, fb, Hb, W, frf, n_poles_vf, max_order):
    """Common-pole vector fit, its order chosen against the data's noise.

    Every pair is scaled to unit peak, and its weights in the fit are the fit weights `W`
    times ``(ORDER_FLOOR / max(sigma_rel, ORDER_FLOOR))^2`` with ``sigma_rel`` the conditioned
    estimate's standard error over the pair's peak: each line counts by its signal-to-noise
    ratio, so noise-dominated pairs and lines (weak cross paths, band edges) no longer place
    common poles for every pair (with unit weights the relocation put lightly damped poles at
    0.8-1.5 Hz, under the car's first mode, into all 308 pairs of a noisy car). Noise-free data
    keep the weights `W`. The order is the smallest even one whose fit errors (weights `W`,
    relative) reach ``max(ORDER_FLOOR, NOISE_FLOOR_FACTOR * noise)`` within 10 % in RMS over
    the pairs, or stop improving by 10 %, plus :data:`VF_ORDER_MARGIN` poles (the residues of
    every pair are refitted with `W` afterwards, by :func:`_regularize`).
    """
    from ident.identify.condition import conditioned_standard_error

    sel = np.searchsorted(frf.f_hz, fb)
    peak = np.maximum(np.abs(Hb).max(axis=-1, keepdims=True), 1e-300)
    Hs = Hb / peak
    sig = conditioned_standard_error(frf)[:, :, sel] / peak
    sig = np.where(np.isfinite(sig), sig, 1.0)
    Wr = W * (ORDER_FLOOR / np.maximum(sig, ORDER_FLOOR)) ** 2
    if n_poles_vf is not None:
        vf = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=int(n_poles_vf))
    else:
        target = np.maximum(ORDER_FLOOR, NOISE_FLOOR_FACTOR * pair_noise_level(frf, sel, W))
        den = np.maximum(np.sum(W * np.abs(Hs) ** 2, axis=-1), 1e-300)
        s = 2j * np.pi * fb
        n_max = 2 * max_order
        chosen, prev = n_max, np.inf
        for n in range(4, n_max + 1, 2):
            cand = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=n)
            fit = np.einsum("kom,kf->omf", cand.residues,
                            1.0 / (s[None, :] - cand.poles[:, None])) + cand.direct[..., None]
            err = np.sqrt(np.sum(W * np.abs(Hs - fit) ** 2, axis=-1) / den)
            e = float(np.sqrt(np.mean(np.maximum(err / target, 1.0) ** 2)))
            if e <= 1.1 or e > (1 - 0.1) * prev:
                chosen = min(n + VF_ORDER_MARGIN if e <= 1.1 else n - 2 + VF_ORDER_MARGIN, n_max)
                break
            prev = e
        vf = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=chosen)
    return dataclasses.replace(vf, residues=vf.residues * peak[None, :, :, 0],
                               direct=vf.direct * peak[:, :, 0])


def identify_session(session, *, estimator="lpm", frf_method="global", cbar_n_s_m=None,
                     nperseg=None,
                     coherence_min=0.9, smooth_width_hz=None, smooth_domain=None,
                     fit_method="invfreqs",
                     orders="auto", weighting="paper", band_hz=(0.5, 20.0), max_order=10):
    """Identify a vehicle model from a rig session: estimate, condition, fit.

    Parameters
    ----------
    session : ident.data.session.Session
    estimator : {"lpm", "welch"}
        FRF estimator (:func:`ident.identify.frf.estimate_frf`): the local polynomial
        method (default; free of the transient leakage that makes Welch H1
        estimates of weak paths noisy) or the paper's Welch H1.
    frf_method : {"global", "sequential"}
        :func:`ident.identify.frf.estimate_frf` (``sequential`` needs ``estimator="welch"``).
    cbar_n_s_m, nperseg
        :func:`ident.identify.frf.estimate_frf`.
    coherence_min, smooth_width_hz, smooth_domain
        :func:`ident.identify.condition.condition_frf` (``smooth_domain`` None: its default).
    fit_method, orders, weighting, band_hz, max_order
        :func:`fit_model`.

    Returns
    -------
    VehicleModel
        ``settings["session"]`` names the session and its runs.
    """
    from ident.identify.condition import condition_frf
    from ident.identify.frf import estimate_frf

    frf = estimate_frf(session, method=frf_method, cbar_n_s_m=cbar_n_s_m, nperseg=nperseg,
                       estimator=estimator)
    frf = condition_frf(frf, coherence_min=coherence_min, smooth_width_hz=smooth_width_hz,
                        **({} if smooth_domain is None else {"smooth_domain": smooth_domain}))
    model = fit_model(frf, method=fit_method, orders=orders, weighting=weighting,
                      band_hz=band_hz, max_order=max_order, name=session.name,
                      units=session.units)
    settings = dict(model.settings, session=session.name,
                    runs=[r.name for r in session.runs], frf_method=frf_method,
                    estimator=estimator)
    return model.with_settings(settings)
