"""The identified vehicle model and its file: rational fits of a conditioned FRF, realized.

A :class:`VehicleModel` (made by :func:`ident.identify.pipeline.fit_model` or
:func:`ident.identify.pipeline.identify_session`) holds the FRF it came from (with
coherence), the fitted pole-residue form of every pair with its fit error, the baseline
damping ``c_bar``, channel names, units and sample rate. The model converts to an
:class:`ident.models.lti.LoopPlant` for closed-loop simulation with any shocks (reduced by
:func:`ident.models.lti.balanced_reduce`), to a python-control state-space system in real
modal form, and to discrete time; it is saved to and loaded from one ``.npz`` file with a
format version (:meth:`VehicleModel.save`, :func:`load_model`; with its reduced loop
plant, so that loading it is all a prediction pays), and exported to MATLAB ``.mat``.
:func:`has_feedthrough` says which pairs have a direct term.

Notes
-----
Every pair ``(o, i)`` is ``H(s) = sum_k r_k / (s - p_k) + d`` over its own
poles (pole-residue form: no polynomial is ever expanded in unscaled ``s``).
Conjugate poles are stored once (``Im p > 0``) with the factor 2 carried by the
realization, as in :class:`ident.models.lti.ModalSystem`.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.data.channels import RIG_INPUTS
from ident.data.files import atomic_path, write_csv
from ident.data.third import CarThird
from ident.errors import ModelFileError
from ident.identify.condition import conditioned_standard_error
from ident.identify.diagnose import Diagnosis
from ident.identify.frf import Frf
from ident.identify.shockcheck import ShockLibraryCheck
from ident.models.bumpstops import CarElements
from ident.models.lti import GRAM_FACTOR_RTOL, LoopPlant, ModalSystem, balanced_reduce

__all__ = [
    "VehicleModel",
    "NoiseReport",
    "RESULT_KEYS",
    "load_model",
    "summary_path",
    "write_model_summary",
    "has_feedthrough",
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "PLANT_VERSION",
    "LOOP_REDUCE_RTOL",
    "RIG_REDUCE_RTOL",
    "NPZ_DEFLATE_LEVEL",
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


#: Default balanced-truncation bound of the shock part for the closed loop (see
#: :meth:`VehicleModel.loop_plant`).
LOOP_REDUCE_RTOL = 3e-2
#: Balanced-truncation bound of the rig part for the closed loop (at most ``reduce_rtol``).
RIG_REDUCE_RTOL = 1e-5

#: A pair whose fit rests on noisy data: relative noise of its conditioned FRF at least this.
NOISE_LIMITED = 0.1
#: :meth:`VehicleModel.noise_bands`: a line rests on noise where the conditioned estimate's
#: relative standard error exceeds this (a signal-to-noise amplitude ratio below 3).
NOISE_BAND_REL_ERROR = 1.0 / 3.0

#: The model's sub-results (:class:`VehicleModel` fields), stored in the model file's
#: settings under these keys, after the settings and in this order.
RESULT_KEYS = ("liftoff", "diagnosis", "shock_check", "noise")


@dataclass(frozen=True)
class NoiseReport:
    """How much an identified model rests on noise: per pair and in metrics.

    Made by :func:`planner.noise.noise_report`; kept with the model
    (:attr:`VehicleModel.noise`) and in its file.

    Attributes
    ----------
    noise_limited_pairs, zero_pairs : int
        Pairs whose conditioned FRF's relative noise is at least :data:`NOISE_LIMITED`,
        and pairs fitted as zero (nothing above the noise).
    expected_metric_error_pct : dict of str to float
        Metric -> half-width of the 95 % interval of its prediction from the
        identification's random error [%].
    reference : dict
        ``run`` and ``setup`` (``LF/RF/LR/RR`` ids) the metric error is computed for.
    """

    noise_limited_pairs: int
    zero_pairs: int
    expected_metric_error_pct: dict
    reference: dict

    def to_dict(self):
        """A JSON-able dict (the model file's ``noise`` entry; :meth:`from_dict` reads it)."""
        return {"noise_limited_pairs": self.noise_limited_pairs, "zero_pairs": self.zero_pairs,
                "expected_metric_error_pct": dict(self.expected_metric_error_pct),
                "reference": dict(self.reference)}

    @classmethod
    def from_dict(cls, doc):
        """The :class:`NoiseReport` of :meth:`to_dict`."""
        return cls(noise_limited_pairs=doc["noise_limited_pairs"], zero_pairs=doc["zero_pairs"],
                   expected_metric_error_pct=dict(doc["expected_metric_error_pct"]),
                   reference=dict(doc["reference"]))

    def lines(self, table):
        """Lines for a terminal: pairs resting on noise and the metric error to expect.

        Parameters
        ----------
        table : pandas.DataFrame
            The model's per-pair summary (:meth:`VehicleModel.summary`): the pairs with
            bands resting on noise are named from it.

        Returns
        -------
        list of str
        """
        half = self.expected_metric_error_pct
        worst = max(half, key=half.get)
        lines = [f"noise: {self.noise_limited_pairs} pairs noise-limited (relative noise of "
                 f"the conditioned FRF >= 10 %), {self.zero_pairs} fitted as zero (nothing "
                 "above the noise); expected metric error from the identification's random "
                 f"error (95 %, the session's run '{self.reference['run']}'): median "
                 f"{np.median(list(half.values())):.3f} %, max {half[worst]:.3f} % ({worst})"]
        banded = table[table.noise_bands_hz != ""].sort_values("noise_level", ascending=False)
        if len(banded):
            lines.append(f"{len(banded)} pairs have bands resting on noise (within 40 dB of "
                         "their peak), e.g.:")
            lines += [f"  {r.output} <- {r.input}: {r.noise_bands_hz} Hz"
                      for r in banded.head(3).itertuples()]
        return lines


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
        How the model was made (fit method, weights, orders, session); ``"elements"``
        the declared bump stops and static loads (:attr:`elements`).
    noise_level : ndarray or None, shape (n_out, n_in)
        Relative noise of each pair's conditioned FRF over the fitted lines
        (:func:`ident.identify.pipeline.pair_noise_level`): the fit error a perfect
        model would have. Pairs at or above
        :data:`ident.identify.pipeline.ZERO_FIT_NOISE` are fitted as zero.
    liftoff : dict or None
        The lift-off correction (:func:`ident.identify.pipeline.identify_session`): the
        lifted samples and pad corrections per run; None when the tires kept the pads.
    diagnosis : ident.identify.diagnose.Diagnosis or None
        What the session shows that the linear model cannot see; None when skipped.
    shock_check : ident.identify.shockcheck.ShockLibraryCheck or None
        The session's shock forces against the library, per shock (without the per-run
        rows); None without force channels.
    noise : NoiseReport or None
        How much the model rests on noise (:func:`planner.noise.noise_report`).

    The sub-results are saved in the model file's settings under :data:`RESULT_KEYS`
    (:meth:`file_settings`) and read back into these fields by :func:`load_model`.
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
    liftoff: dict | None = None
    diagnosis: Diagnosis | None = field(default=None, repr=False)
    shock_check: ShockLibraryCheck | None = field(default=None, repr=False)
    noise: NoiseReport | None = None
    _plants: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def elements(self):
        """CarElements or None: The bump stops, the baseline's stops and packers and the
        static corner loads the session declared (``settings["elements"]``, written by
        :func:`ident.identify.pipeline.identify_session`; saved and loaded with the model);
        None for a model identified without any."""
        doc = self.settings.get("elements")
        return None if doc is None else CarElements.from_dict(doc)

    @property
    def third(self):
        """CarThird or None: The heave and roll elements the session declared and the
        baseline run's fit (``settings["third"]``, written by identification; saved and
        loaded with the model); None for a car without third elements."""
        doc = self.settings.get("third")
        return None if doc is None else CarThird.from_dict(doc)

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
        ident.models.lti.ModalSystem
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
        """The model as an :class:`ident.models.lti.LoopPlant` for closed-loop simulation.

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
        return self.with_results(settings=settings)

    def with_results(self, **changes):
        """A copy with other settings or sub-results that keeps the loop plants built so far
        (they depend on neither; :meth:`loop_plant`).

        Parameters
        ----------
        **changes
            ``settings`` and any of :data:`RESULT_KEYS` (``liftoff``, ``diagnosis``,
            ``shock_check``, ``noise``).

        Returns
        -------
        VehicleModel

        Raises
        ------
        TypeError
            For another field (a changed array changes the loop plant: build a new model).
        """
        other = set(changes) - {"settings", *RESULT_KEYS}
        if other:
            raise TypeError(f"with_results() takes settings and {', '.join(RESULT_KEYS)}, not "
                            f"{', '.join(sorted(other))}; a model with other arrays is a new "
                            "VehicleModel")
        new = dataclasses.replace(self, **changes)
        new._plants.update(self.__dict__.get("_plants", {}))
        return new

    def file_settings(self):
        """The settings as the model file stores them: :attr:`settings`, then the
        sub-results' documents under :data:`RESULT_KEYS` (those the model has).

        Returns
        -------
        dict
            JSON-able after :meth:`save`'s conversion of numpy scalars and arrays.
        """
        out = dict(self.settings)
        docs = {"liftoff": self.liftoff,
                "diagnosis": None if self.diagnosis is None else self.diagnosis.to_dict(),
                "shock_check": (None if self.shock_check is None else
                                self.shock_check.to_dict(series=False)),
                "noise": None if self.noise is None else self.noise.to_dict()}
        out.update({k: v for k, v in docs.items() if v is not None})
        return out

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
        conditioned FRF, :func:`ident.identify.pipeline.pair_noise_level`; NaN if
        unknown), ``status`` (``fit``; ``zero`` for a pair fitted as zero because nothing in it is
        above the noise; ``noise-limited`` for a fit whose error is at the
        noise level and above :data:`NOISE_LIMITED`) and ``noise_bands_hz``
        (:meth:`noise_bands`, as text). ``attrs["elements"]`` says which bump stops and
        static loads the model was identified with (:meth:`CarElements.describe`).
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
        table = pd.DataFrame(rows)
        elements = self.elements
        table.attrs["elements"] = (elements.describe() if elements is not None else
                                   "no bump stops or static loads declared")
        return table

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
        """Save to one compressed ``.npz`` file (atomic), with the format name and version.

        The values are stored exactly (deflate is lossless); :func:`load_model` reads
        compressed and uncompressed (earlier) files alike.

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
                "fs_hz": self.fs_hz, "units": self.units,
                "settings": _jsonable(self.file_settings()),
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
            if fr.cv_deviation is not None:
                arrays["frf_cv_deviation"] = fr.cv_deviation
            if fr.noise_bias is not None:
                arrays["frf_noise_bias"] = fr.noise_bias
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
        # deflated: the FRF's noisy complex lines compress by 15 % only (paper session:
        # 27.1 MB against 31.8 MB stored), but the demo folder holds one; np.load reads stored
        # and deflated files alike (files of earlier versions). Deflate level 1: the same
        # arrays, 0.9 % larger than numpy's level 6, in 0.6 of its time (paper session)
        _savez_deflated(buf, {"meta": np.array(json.dumps(meta)), **arrays},
                        level=NPZ_DEFLATE_LEVEL)
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


#: zlib level of the model file's deflated members (:meth:`VehicleModel.save`).
NPZ_DEFLATE_LEVEL = 1


def _savez_deflated(file, arrays, *, level):
    """``numpy.savez_compressed(file, **arrays)`` with deflate level `level`: the same members
    (``<key>.npy``, numpy's format), read back by ``np.load`` as they were written."""
    with zipfile.ZipFile(file, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True,
                         compresslevel=level) as zf:
        for key, value in arrays.items():
            with zf.open(key + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=True)


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
                      replaced=data.get("frf_replaced"), sigma=data.get("frf_sigma"),
                      cv_deviation=data.get("frf_cv_deviation"),
                      noise_bias=data.get("frf_noise_bias"))
        settings = dict(meta.get("settings", {}))
        docs = {k: settings.pop(k, None) for k in RESULT_KEYS}
        model = VehicleModel(name=meta["name"], input_names=tuple(meta["input_names"]),
                             output_names=tuple(meta["output_names"]), poles=data["poles"],
                             residues=data["residues"], direct=data["direct"],
                             n_poles=data["n_poles"], order=data["order"],
                             fit_error=data["fit_error"], cbar_n_s_m=data["cbar_n_s_m"],
                             fs_hz=float(meta["fs_hz"]), units=meta.get("units", "SI"), frf=frf,
                             settings=settings, noise_level=data.get("noise_level"),
                             liftoff=docs["liftoff"],
                             diagnosis=(None if docs["diagnosis"] is None else
                                        Diagnosis.from_dict(docs["diagnosis"])),
                             shock_check=(None if docs["shock_check"] is None else
                                          ShockLibraryCheck.from_dict(docs["shock_check"])),
                             noise=(None if docs["noise"] is None else
                                    NoiseReport.from_dict(docs["noise"])))
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


def summary_path(model_path):
    """Where ``shockplan identify`` writes a model's per-pair summary: beside the model,
    ``<stem>_summary.csv`` (``model.npz`` -> ``model_summary.csv``, as the demo's).

    Parameters
    ----------
    model_path : str or Path

    Returns
    -------
    pathlib.Path
    """
    model_path = Path(model_path)
    return model_path.with_name(f"{model_path.stem}_summary.csv")


def write_model_summary(model, path, *, units="SI", overwrite=False):
    """Write :meth:`VehicleModel.summary` (order, fit error, coherence, noise level and
    status of every input/output pair) as CSV, atomically.

    The last column is ``units`` (`units` on every row: the summary's values have no
    unit; the column says the unit system of the session it came from).

    Parameters
    ----------
    model : VehicleModel
    path : str or Path
        Output file, e.g. :func:`summary_path` of the model's file.
    units : {"SI", "imperial"}
        The unit system of the run that writes it (the session's).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    if not isinstance(model, VehicleModel):
        raise TypeError(f"write_model_summary: model must be a VehicleModel, got "
                        f"{type(model).__name__}")
    path = Path(path)
    write_csv(path, model.summary(), units=units, overwrite=overwrite)
    return path
