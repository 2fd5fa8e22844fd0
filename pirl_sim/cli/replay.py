"""``pirl-sim replay``: learn from recorded tracks and score predictions against them, through the sweep engine.

The options are one frozen, validated `ReplayOptions` (its fields declare the parser:
`ReplayOptions.add_arguments`), made once from the command line (`ReplayOptions.from_args`);
`ReplayOptions.resolve` fills in the defaults that depend on the data (`ReplaySettings`), whose
`ReplaySettings.config` is the sweep config: the scenario ``recorded`` (`pirl_sim.experiments.recorded`), or with
``--scan-horizon`` the ``horizon-scan`` kind (`pirl_sim.experiments.horizon_scan`). It runs with
`pirl_sim.engine.run.run_sweep` into ``--out``, then the report template
`pirl_sim.experiments.replay_report.write_replay_results` (and `pirl_sim.experiments.replay_table` with
``--table``).

The options, presets and the defaults that depend on the data are explained in the documentation's "Replay of
recorded driving" page.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pirl_sim.validation import list_arg, positive_float_arg, positive_int_arg

from .common import (command_line, driver_settings, error, finish, interrupted, print_plan, reworded,
                     seconds_to_steps, subcommand, table_text)

if TYPE_CHECKING:
    from pirl_sim.experiments.recorded import ReplayProtocol
    from pirl_sim.scenarios.replay import DriverSettings, EstimateNoise

__all__ = ["add_parser", "run", "ReplayOptions", "ReplaySettings", "replay_results", "PRESETS", "data_preset"]

#: the default roundabouts of ``--table`` (INTERACTION names)
DEV_ROUNDABOUTS = ("DR_USA_Roundabout_EP", "DR_USA_Roundabout_FT", "DR_CHN_Roundabout_LN")
PIECE_DURATION = 20.0  # [s] longer tracks are cut into pieces of this duration (a whole roundabout passage)
NEXT_KNN = "pirl-knn-next"  #: PIRL-kNN with target="next" (learners/knn.py), a key of --learners only
SELECT = "pirl-select"  #: the same costs chosen by a learned forecast (aggregate="selected"), a key of --learners only
LEARNERS = ("tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn", NEXT_KNN, SELECT)  #: the keys of --learners
# irl_max_iter 400: on DR_USA_Roundabout_FT 1-2 of ~730 per-demo fits needed more than 100 (x5), on EP 2 of
# 10,624 next segments
_KNN = {"prior": "population", "stride": 2, "irl_max_iter": 400}
# costs of what followed each training window, looked up by the speed and acceleration along the path (state
# entries 1, 2) now, 0.5 s and 1 s ago and the road's curvature ahead (`ReplaySettings.learner_entries`)
_NEXT = {**_KNN, "target": "next", "state_features": (1, 2), "lookup_features": False}
#: the sweep config's learner entry of each --learners key and pseudo-learner, before the options' parameters
LEARNER_ENTRIES: dict[str, dict[str, Any]] = {
    "cv": {"name": "cv", "label": "CV (path)"}, "ca": {"name": "ca", "label": "CA (path)"}, "tirl": {"name": "tirl"},
    "pirl-gmm": {"name": "pirl-gmm", "params": {"random_state": 0}},
    "pirl-dpgmm": {"name": "pirl-dpgmm", "params": {"random_state": 0}},
    "pirl-knn": {"name": "pirl-knn", "params": _KNN},
    NEXT_KNN: {"name": "pirl-knn", "label": "PIRL-kNN next", "params": {**_NEXT, "aggregate": "futures"}},
    # no look-up: a bank of 256 of those costs, mixed online to come nearest to a forecast of the next seconds
    # from the same keys and the place (learners/selector.py)
    SELECT: {"name": "pirl-knn", "label": "PIRL-select",
             "params": {**_NEXT, "aggregate": "selected", "selector": "forecast", "n_candidates": 256}},
    "hindsight": {"name": "hindsight", "label": "hindsight cost (oracle)"},
    "direct": {"name": "direct", "label": "direct regression (no cost)"},  # pirl_sim.evaluation.direct
    "cv-xy": {"name": "cv-xy", "label": "CV (x, y)"}}

#: what ``--preset best`` sets of the options not given: the configuration of the README's real-roundabout table
_BEST = {"desired_speed": "fit", "features": "speed-level", "lateral": "neighbours", "selection": "free",
         "learners": ("tirl", "pirl-gmm", "pirl-knn", NEXT_KNN, SELECT)}
#: what ``--preset paper`` sets: the paper's configuration
_PAPER = {"desired_speed": "fixed", "features": "paper", "lateral": "hold", "selection": "tracks",
          "learners": ("tirl", "pirl-gmm", "pirl-knn")}
PRESETS = {"best": _BEST, "paper": _PAPER}  #: the settings of each ``--preset``


def data_preset(tracks: Path, preset: str) -> dict:
    """The `PRESETS` entry ``preset`` for the drivers of ``tracks``: drivers whose model is known (a pirl_sim
    recording, or a ``ground_truth.csv`` beside the tracks) keep their own features and desired speed and the
    paper's selection, whatever the preset."""
    from pirl_sim.scenarios.replay import GROUND_TRUTH_FILE, is_recording

    folder = tracks if tracks.is_dir() else tracks.parent
    return _PAPER if is_recording(tracks) or (folder / GROUND_TRUTH_FILE).is_file() else PRESETS[preset]


def _preset_text(settings: dict) -> str:
    """A preset's settings as options: ``desired-speed fit, features speed-level, ...``."""
    return ", ".join(f"{k.replace('_', '-')} {','.join(v) if isinstance(v, tuple) else v}" for k, v in settings.items())


#: a field's annotation (without ``| None``) -> its option's argparse arguments (those of the field's metadata aside)
_ARGPARSE: dict[str, dict[str, Any]] = {"Path": {"type": Path}, "bool": {"action": "store_true"}, "str": {"type": str},
             "int": {"type": positive_int_arg}, "float": {"type": positive_float_arg},
             "tuple[int, ...]": {"type": list_arg(int, low=1)}, "tuple[str, ...]": {"type": list_arg(str, empty=True)},
             "tuple[float, ...]": {"type": list_arg(float, low=0, empty=True)}}


def _option(default, help: str, **argparse_kwargs):
    """A field of `ReplayOptions`: its default, its ``--help`` text and what else its option needs (choices,
    metavar, a type of its own)."""
    return dataclasses.field(default=default, metadata={"help": help, **argparse_kwargs})


def _argparse(f: dataclasses.Field) -> dict:
    """The argparse arguments of the option of the `ReplayOptions` field ``f`` besides its name and default."""
    return {**_ARGPARSE[f.type.removesuffix(" | None")], **f.metadata}


@dataclasses.dataclass(frozen=True)
class ReplayOptions:
    """The options of ``pirl-sim replay``, each under its option's name (``--mpc-horizon``: ``mpc_horizon``) with
    the type the command line gives it; each field's help says its unit and default. ``lateral`` and ``learners``
    not given take ``preset``'s value here; ``features``, ``desired_speed`` and ``selection`` not given take it in
    `resolve`, as they also depend on the data (`data_preset`); other None: the default that depends on the data
    (module doc; `resolve`).

    Raises
    ------
    ValueError
        A value its option would not take (naming the field, the value and what is allowed), neither
        ``tracks`` and ``map`` nor ``table``, unknown learners, or options that contradict each other.
    """

    tracks: Path | None = _option(None, "a vehicle_tracks_*.csv file or a directory of them")
    map: Path | None = _option(None, "the Lanelet2 OSM map of the recording")
    table: Path | None = _option(None, "instead of --tracks/--map: run every roundabout of --roundabouts from an "
                                 "INTERACTION folder ROOT (ROOT/recorded_trackfiles/NAME/vehicle_tracks_*.csv, "
                                 "ROOT/maps/NAME.osm) and write one table (table.md/.csv) and each roundabout's "
                                 "results in --out/NAME", metavar="ROOT")
    roundabouts: tuple[str, ...] = _option(DEV_ROUNDABOUTS, f"names for --table (default {','.join(DEV_ROUNDABOUTS)})")
    files: int | None = _option(None, "use only the first N track files (sorted by name) of each recording (default "
                                "all)")
    futures: int | None = _option(None, "also score K predicted futures per window and learner: minADE_K, minFDE_K, "
                                  "INTERACTION miss rate, mixture NLL per step (columns min_ade@K ... in rows.csv; "
                                  "default: off)", metavar="K")
    hindsight: bool = _option(False, "also score each test window under the cost fitted on its own recorded future (an "
                              "oracle row, 'hindsight cost (oracle)': what the model class reaches with perfect "
                              "weights; not a predictor, never the best PIRL learner)")
    direct: bool = _option(False, "also score a regression without a cost: the arc lengths over the horizon regressed "
                           "on the history's speeds and accelerations, the road ahead and the place (row 'direct "
                           "regression (no cost)', pirl_sim.evaluation.direct): how much the history and the map tell; "
                           "never the best PIRL learner")
    preset: str = _option("best", "the settings of --desired-speed, --features, --lateral, --learners and --selection "
                          "that are not given (drivers whose model is known, a pirl_sim recording or tracks with a "
                          "ground_truth.csv, keep their own features and desired speed and the paper's selection): "
                          f"'best' (the configuration of the README's real-roundabout table: {_preset_text(_BEST)}) or "
                          f"'paper' (the paper's: {_preset_text(_PAPER)}) (default best)", choices=("best", "paper"))
    desired_speed: str | None = _option(None, "the desired speed's a_lat and v_max: 'fit' on each split's training "
                                        "tracks (robust fit of speeds against curvature, pirl_sim.speed_fit) or "
                                        "'fixed' (--a-lat, --v-max) (default: --preset's)", choices=("fit", "fixed"))
    a_lat: float | None = _option(None, "lateral-acceleration limit [m/s^2] of the desired speed (default 1.8; a "
                                  "pirl_sim recording's drivers' value)")
    v_max: float | None = _option(None, "speed cap [m/s] of the desired speed (default 13.9; a pirl_sim recording's "
                                  "drivers' value)")
    features: str | None = _option(None, "the cost's features: 'paper' (speed_dev, acc_sq, jerk_sq), 'speed-level' "
                                   "(also speed_sq and speed_hi: a speed level of each driver's own) or 'following' "
                                   "(speed-level and headway: the gap to the recorded vehicle ahead, held at constant "
                                   "velocity over a prediction, and the conflict points a car yields at; selection defaults to 'all') "
                                   "or 'interacting' (paper, headway to the vehicle ahead and yielding to a standing "
                                   "obstacle before a conflict point: the simulated drivers' cost when their "
                                   "population weighs headway and yielding) "
                                   "(pirl_sim.driving.roundabout_features) (default: --preset's)",
                                   choices=("paper", "speed-level", "following", "interacting"))
    lateral: str | None = _option(
        None, "lateral offsets of every path-based prediction (baselines and learners): 'hold' the last observed one, "
        "or follow the training tracks' 'mean-path' of the route, or their mean path pooled over routes in the "
        "'plane', or that plus the change of deviation of the nearest training windows in the plane, 'neighbours' "
        "(pirl_sim.lateral) (default: --preset's)", choices=("hold", "mean-path", "plane", "neighbours"))
    start: str = _option("history", "the states every prediction starts from and its learners see: estimated from the "
                         "2 s history alone ('history': what an online predictor knows), or the whole track's estimate "
                         "('track': a smoother that also saw the future it predicts) (default history)",
                         choices=("history", "track"))
    learners: tuple[str, ...] | None = _option(
        None, "comma-separated learners: tirl, pirl-gmm, pirl-dpgmm, pirl-knn, pirl-knn-next (PIRL-kNN with costs of "
        "what followed each training window, looked up by the speed and acceleration now, 0.5 s and 1 s ago and the "
        "road ahead, its neighbours' futures averaged: learners/knn.py), pirl-select (the same costs, a bank of them "
        "mixed to come nearest to a forecast of the next seconds from the same keys and the place: "
        "learners/selector.py) (default: --preset's)")
    next_segments: str | None = _option(
        None, "pirl-knn-next, pirl-select: where each training segment whose cost the IRL fits starts: at its "
        "history's own estimate, the state an online prediction starts from ('history'), or at the smoothed track's "
        "state ('track') (default: history with --start history)", choices=("history", "track"))
    lookup_ahead: tuple[float, ...] = _option((0.0, 10.0, 20.0, 30.0, 45.0), "pirl-knn-next, pirl-select: distances "
                                              "ahead [m] at which the road's curvature joins the look-up keys ('' "
                                              "none) (default 0,10,20,30,45)", metavar="M1,M2,...")
    ahead_weights: tuple[float, ...] = _option((0.0, 0.5, 1.0), "pirl-knn-next: candidate weights of the road ahead in "
                                               "the look-up; with several, each split chooses the one that predicts "
                                               "held-out training windows best (learners/knn.py) (default 0,0.5,1)",
                                               metavar="W1,W2,...")
    gmm_k: int = _option(3, "clusters of PIRL-GMM (default 3)")
    knn_k: tuple[int, ...] = _option((10,), "neighbours of PIRL-kNN; several comma-separated values run one learner "
                                     "each and draw MED vs k (default 10)")
    seeds: int = _option(3, "number of train/test split seeds (default 3)")
    workers: int = _option(1, "split seeds run in this many sweep worker processes at once (default 1: in this "
                           "process; the results do not depend on it)")
    history: float = _option(2.0, "observed history [s], at least one step of --dt (default 2)")
    horizon: float = _option(3.0, "predicted horizon [s], at least one step of --dt (default 3)")
    likelihood: str = _option("trajectory", "the IRL's model of a demonstration: 'trajectory' (the paper's: one "
                              "open-loop optimum) or 'receding' (each step's control is the first of an MPC plan over "
                              "--mpc-horizon steps) (default trajectory)", choices=("trajectory", "receding"))
    mpc_horizon: int | None = _option(
        None, "the drivers' MPC horizon [steps of --dt] for --likelihood receding and closed-loop rollouts (default: "
        "drivers.horizon of a pirl_sim recording's run.json; required for real data)", metavar="H",
        type=reworded(positive_int_arg, "--mpc-horizon must be a positive number of steps, got {text!r}"))
    dt: float | None = _option(None, "model step [s], a multiple of the 0.1 s frames (default 0.2, the paper's; with "
                               "--likelihood receding on a pirl_sim recording its drivers' re-planning step)")
    estimate: str | None = _option(None, "state estimate from positions only or from positions and recorded speeds "
                                   "(default: speeds, positions with --start track and the trajectory likelihood)",
                                   choices=("positions", "speeds"))
    sigma_v: float | None = _option(None, "speed noise [m/s] of --estimate speeds (default 0.05 for real data, 0.001 "
                                    "for pirl_sim recordings)")
    sigma_j: float | None = _option(None, "jerk prior [m/s^3] of --estimate speeds (default 1 for real data, 3 for "
                                    "pirl_sim recordings)")
    selection: str | None = _option(
        None, "'tracks': whole tracks without a leader (the paper's); 'free': every track cut into its free-flow runs "
        "(steps with a leader closer than 3 m bumper to bumper + 1.5 s x speed left out); 'steps': every PIRL track "
        "with a per-step mask from driver_steps.csv (pirl_sim recordings, --likelihood receding only); 'all': every "
        "track whole, leaders included (for --features following). Default: steps where driver_steps.csv exists and "
        "the likelihood is receding, all with --features following, else --preset's",
        choices=("tracks", "steps", "free", "all"))
    rollout: str | None = _option(None, "learners' predictions: 'open' (one MPC plan) or 'closed' (re-plan every step "
                                  "over --mpc-horizon steps, as the drivers) (default: closed with --likelihood "
                                  "receding, open otherwise)", choices=("open", "closed"))
    scan_horizon: tuple[int, ...] | None = _option(None, "instead of the replay: for each MPC horizon [steps], fit "
                                                   "TIRL with the receding likelihood on the training tracks and "
                                                   "report the held-out residual NLL per step and MED "
                                                   "(horizon_scan.csv/.md)", metavar="H1,H2,...")
    out: Path = _option(Path("results") / "replay", "output directory")
    quiet: bool = _option(False, "no progress lines on stderr")
    dry_run: bool = _option(False, "validate the options and the scene's files, count the cells (one per split seed "
                            "and method) and those already in --out; run nothing")

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # a value its option gives: the option's type reads it back unchanged
            value, kwargs = getattr(self, f.name), _argparse(f)
            if value is None and f.default is None or isinstance(value, bool) and "action" in kwargs:
                continue
            try:
                text = ",".join(map(str, value)) if isinstance(value, tuple) else str(value)
                ok = "type" in kwargs and kwargs["type"](text) == value and value in kwargs.get("choices", (value,))
            except argparse.ArgumentTypeError as exc:
                raise ValueError(f"{f.name}={value!r}: {exc}") from None
            if not ok:
                allowed = f"one of {kwargs['choices']}" if "choices" in kwargs else f"a value of type {f.type}"
                raise ValueError(f"{f.name}={value!r}: expected {allowed}")
        for name in ("lateral", "learners"):  # the options not given that do not depend on the data: the preset's
            if getattr(self, name) is None:
                object.__setattr__(self, name, PRESETS[self.preset][name])
        if self.table is None and (self.tracks is None or self.map is None):
            raise ValueError("replay needs --tracks and --map (or --table ROOT)")
        unknown = [k for k in self.learners if k not in LEARNERS]  # type: ignore[union-attr]  # learners set above
        if unknown or not self.learners:
            raise ValueError(f"unknown learners {unknown or list(self.learners)}; "  # type: ignore[arg-type]
                             f"choose from {sorted(LEARNERS)}")
        if self.selection == "steps" and self.likelihood != "receding":
            raise ValueError("--selection steps needs --likelihood receding: the trajectory likelihood scores whole "
                             "trajectories and cannot leave the overridden steps out")
        if self.next_segments == "history" and self.start != "history" and {NEXT_KNN, SELECT} & set(self.learners):
            raise ValueError("--next-segments history starts the training segments at their histories' own "
                             "estimates, which --start track does not make: use --start history")

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Add the option ``--a-b`` of each field ``a_b`` to ``parser``, its type from the field's annotation."""
        for f in dataclasses.fields(cls):
            parser.add_argument(f"--{f.name.replace('_', '-')}", default=f.default, **_argparse(f))

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ReplayOptions:
        """The options of a namespace parsed by a parser of `add_arguments` (other attributes ignored).

        Raises
        ------
        ValueError
            Options that contradict each other on the command line: ``--table`` with ``--tracks`` or ``--map``,
            ``--roundabouts`` without ``--table``, or an ``--out`` that is an existing file.
        """
        options = cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls)})
        if options.table is not None and (options.tracks is not None or options.map is not None):
            raise ValueError("--table ROOT replaces --tracks and --map (it reads ROOT/recorded_trackfiles/NAME and "
                             "ROOT/maps/NAME.osm): give one or the other")
        if options.table is None and options.roundabouts != DEV_ROUNDABOUTS:
            raise ValueError("--roundabouts names the roundabouts of --table ROOT: without --table it does nothing")
        if options.out.exists() and not options.out.is_dir():
            raise ValueError(f"--out {str(options.out)!r} is a file, not a directory: results would overwrite it")
        return options

    def resolve(self) -> ReplaySettings:
        """These options with the defaults that depend on the data (module doc) filled in from ``tracks``.

        Raises
        ------
        ValueError
            A receding likelihood or closed rollout without an MPC horizon, ``dt`` other than a recording's
            re-planning step with its horizon, ``selection="steps"`` without ``driver_steps.csv``.
        """
        from pirl_sim.scenarios.replay import (DRIVER_STEPS_FILE, MEASURED_NOISE, SIMULATED_NOISE, EstimateNoise,
                                               is_recording, recording_settings)

        tracks = self.tracks
        assert tracks is not None  # __post_init__: --tracks unless --table, which resolves each roundabout's
        rec, receding, notes = recording_settings(tracks), self.likelihood == "receding", []
        if self.dt is None and receding and rec is not None:
            notes.append(f"--dt {rec.dt:g} s: the drivers' re-planning step (run.json)")
        dt = float(self.dt) if self.dt is not None else rec.dt if receding and rec is not None else 0.2
        horizon = self.mpc_horizon
        if horizon is None and rec is not None:
            if abs(dt - rec.dt) < 1e-9:
                horizon = rec.horizon
                notes.append(f"--mpc-horizon {horizon}: the drivers' drivers.horizon (run.json)")
            elif receding:
                raise ValueError(f"--dt {dt:g} s differs from the drivers' re-planning step {rec.dt:g} s, so their "
                                 f"horizon of {rec.horizon} steps does not apply: give --mpc-horizon in steps of --dt")
        horizon = horizon or (self.scan_horizon[0] if self.scan_horizon else None)  # a scan sets its own
        rollout = self.rollout or ("closed" if receding else "open")
        if (receding or rollout == "closed") and horizon is None:
            raise ValueError(f"{'--likelihood receding' if receding else '--rollout closed'} needs the drivers' MPC "
                             f"horizon: give --mpc-horizon H (steps of --dt = {dt:g} s); {self.tracks} is not a "
                             "pirl_sim recording with a run.json to take it from")
        steps_file = (tracks if tracks.is_dir() else tracks.parent) / DRIVER_STEPS_FILE
        simulated, preset = is_recording(tracks), data_preset(tracks, self.preset)
        features, desired_speed = self.features or preset["features"], self.desired_speed or preset["desired_speed"]
        selection = self.selection or ("steps" if receding and steps_file.is_file() else
                                       "all" if features in ("following", "interacting") else preset["selection"])
        if selection == "steps" and not steps_file.is_file():
            raise ValueError(f"--selection steps needs {DRIVER_STEPS_FILE} beside the tracks (pirl_sim recordings); "
                             f"none in {steps_file.parent}")
        # history starts: a position-only fit over 2 s damps the jerks so hard that its last speed lags the car's
        estimate = self.estimate or ("speeds" if receding or self.start == "history" else "positions")
        base = SIMULATED_NOISE if simulated else MEASURED_NOISE
        noise = EstimateNoise(base.sigma_s, self.sigma_v or base.sigma_v, self.sigma_j or base.sigma_j, base.sigma_a)
        if rec is not None:
            notes.append(f"model: the drivers' path smoothing {rec.smoothing:g} m, desired-speed smoothing "
                         f"{rec.speed_smoothing:g} m, a_lat {rec.a_lat:g}, v_max {rec.v_max:g} (run.json)")
        return ReplaySettings(self, dt, horizon, rollout, selection, estimate, noise, rec, simulated, features,
                              desired_speed, tuple(notes))


def _steps(seconds: float, dt: float) -> int:
    return max(1, int(round(seconds / dt)))


@dataclasses.dataclass(frozen=True)
class ReplaySettings:
    """`ReplayOptions` with the defaults that depend on the data resolved (`ReplayOptions.resolve`).

    Attributes
    ----------
    options : ReplayOptions      as given
    dt : float                   [s] model step
    mpc_horizon : int or None    [steps of dt] the drivers' MPC horizon (with a scan and none given: its first)
    rollout, selection, estimate, features, desired_speed : str   as the options, resolved
    noise : EstimateNoise        of the state estimate
    recording : DriverSettings or None  the drivers' settings from a pirl_sim recording's ``run.json``
    simulated : bool             whether the tracks are a pirl_sim recording (a ``run.json`` beside them)
    notes : tuple of str         the defaults taken from ``run.json``, to tell the user
    """

    options: ReplayOptions
    dt: float
    mpc_horizon: int | None
    rollout: str
    selection: str
    estimate: str
    noise: EstimateNoise
    recording: DriverSettings | None
    simulated: bool
    features: str = "paper"
    desired_speed: str = "fixed"
    notes: tuple[str, ...] = ()

    def protocol(self) -> ReplayProtocol:
        """The windows in steps of `dt` (a stride of 1 s), the split seeds and the rest of the protocol.

        Raises
        ------
        ValueError
            ``history`` or ``horizon`` [s] shorter than half a step, named.
        """
        from pirl_sim.experiments.recorded import ReplayProtocol

        o, dt = self.options, self.dt
        return ReplayProtocol(history=seconds_to_steps(o.history, dt, "--history"),
                              horizon=seconds_to_steps(o.horizon, dt, "--horizon"),
                              fde_steps=tuple(sorted({_steps(x, dt) for x in (1.0, 2.0, o.horizon) if x <= o.horizon})),
                              stride=_steps(1.0, dt), seeds=tuple(range(o.seeds)), rollout=self.rollout,
                              mpc_horizon=self.mpc_horizon, lateral=o.lateral,  # type: ignore[arg-type]  # a preset's
                              start=o.start)

    def load(self) -> dict:
        """How the scene is read: keyword arguments of `pirl_sim.scenarios.replay.load_replay` besides the files
        and the map, as JSON data (the ``recorded`` kind's parameter ``load``)."""
        return {"dt": self.dt, "estimate": self.estimate, "noise": dataclasses.asdict(self.noise),
                "selection": self.selection, "max_steps": _steps(PIECE_DURATION, self.dt), "features": self.features,
                **({"arc_length": "observed"} if self.simulated else {}),  # the positions simulated drivers plan from
                **driver_settings(self.recording, self.options.a_lat, self.options.v_max)}

    def learner_entries(self) -> list[dict]:
        """The sweep config's learner entries in the order of the report's rows: CV and CA along the path, the
        learners in the order of ``learners`` (TIRL first when not named: the reference of the paired
        differences), the hindsight oracle and the direct regression when asked for, CV (x, y).

        With the receding likelihood every learner fits it over `mpc_horizon` (without kNN's population prior, a
        prior of the trajectory likelihood's Laplace fit); PIRL-GMM has ``gmm_k`` clusters, PIRL-kNN the k-grid
        ``knn_k``; the next-segment learners look the road up ``lookup_ahead`` [m] ahead with ``ahead_weights``
        and start their training segments as ``next_segments`` says.
        """
        from pirl_sim.experiments.recorded import history_lags

        o, p = self.options, self.protocol()
        rank = {k: i for i, k in enumerate(o.learners)}  # type: ignore[arg-type]  # set by __post_init__
        irl = ({"likelihood": "receding", "horizon": int(p.mpc_horizon)}  # type: ignore[arg-type]  # resolve: given
               if o.likelihood == "receding" else {})
        entries = [dict(LEARNER_ENTRIES["cv"]), dict(LEARNER_ENTRIES["ca"])]
        for key in ([] if "tirl" in rank else ["tirl"]) + sorted(rank, key=rank.__getitem__):
            params = {k: v for k, v in LEARNER_ENTRIES[key].get("params", {}).items() if not (irl and k == "prior")}
            params.update(irl, **({"n_components": o.gmm_k} if key == "pirl-gmm" else {}))
            if key in (NEXT_KNN, SELECT):
                params.update(target_steps=p.horizon, state_lags=history_lags(self.dt, p.history),
                              lookup_history=p.start == "history", segment_start=o.next_segments or p.start,
                              lookup_ahead=list(o.lookup_ahead), ahead_weights=list(o.ahead_weights))
            grid = {"grid": {"n_neighbors": list(o.knn_k)}} if key in ("pirl-knn", NEXT_KNN) else {}
            entries.append({**LEARNER_ENTRIES[key], "params": params, **grid})
        extras = [k for k in ("hindsight", "direct") if getattr(o, k)]
        return entries + [dict(LEARNER_ENTRIES[k]) for k in (*extras, "cv-xy")]

    def config(self):
        """The validated sweep config (`pirl_sim.engine.config.SweepConfig`): one experiment of the ``recorded``
        kind over the split seeds 0 .. ``seeds`` - 1, a cell per seed and learner entry (`learner_entries`);
        with ``scan_horizon``, the ``horizon-scan`` kind over the same scene and windows, a cell per seed and
        MPC horizon.

        Raises
        ------
        ValueError
            Anything the sweep config rejects (named there), e.g. a data file it cannot read.
        """
        from pirl_sim.engine.config import parse_config
        from pirl_sim.experiments.horizon_scan import LEARNER

        o, p, scan = self.options, self.protocol(), self.options.scan_horizon is not None
        learners = [{"name": LEARNER, "grid": {"horizon": list(o.scan_horizon)}}] if scan else self.learner_entries()
        if not scan and p.rollout != "open":
            from pirl_sim.learners.knn import MIXTURES

            mixing = [e.get("label", e["name"]) for e in learners if e.get("params", {}).get("aggregate") in MIXTURES]
            if o.futures or mixing:
                what = f"--futures {o.futures}" if o.futures else f"{', '.join(mixing)} (averaging or choosing futures)"
                raise ValueError(f"--rollout {p.rollout} re-plans at every step (the default with --likelihood "
                                 f"receding), but {what} predicts open-loop plans: give --rollout open, or --learners "
                                 "without them")
        replay = {"fde_steps": list(p.fde_steps), "lateral": p.lateral, "start": p.start,
                  **({"desired_speed": "fit"} if self.desired_speed == "fit" else {}),
                  **({} if scan else {"rollout": p.rollout, "n_futures": o.futures or 0}),
                  **({"mpc_horizon": p.mpc_horizon} if p.mpc_horizon is not None and not scan else {})}
        exp = {"scenario": "horizon-scan" if scan else "recorded", "label": "horizon scan" if scan else "replay",
               "learners": learners,
               "protocols": [{"kind": "rolling", "history_steps": p.history, "horizon": p.horizon, "stride": p.stride}],
               "params": {"tracks": str(o.tracks), "map": str(o.map), "files": o.files or 0, "load": self.load(),
                          "replay": replay}}
        return parse_config({"name": "replay", "description": "Learners and baselines predicting recorded tracks 3 s "
                             "ahead from a 2 s history, scored in metres over split seeds.",
                             "seeds": list(range(o.seeds)), "experiments": [exp]},
                            source="<replay --scan-horizon>" if scan else "<replay>")


@subcommand("replay", help="learn from recorded tracks (INTERACTION format) and score predictions against them",
            description="Replay INTERACTION-format track files on their Lanelet2 map: select non-interacting "
            "drivers, fit the learners, predict each test track from a history window, score MED/ADE/FDE in metres "
            "against baselines over several split seeds.")
def add_parser(rp) -> None:
    """The options of ``replay``: `ReplayOptions.add_arguments`."""
    ReplayOptions.add_arguments(rp)


def replay_results(config, run, scene, proto) -> dict:
    """The report template's result dict (`pirl_sim.experiments.replay_report.collect_replay`) from the stored cells
    of a finished `run_sweep` of ``config`` (a `ReplaySettings.config` with the protocol ``proto``; every cell
    finished: `SweepRun.check_failed` passed) over ``scene`` (the scene its cells replayed)."""
    from pirl_sim.experiments.recorded import decode_method, method_id
    from pirl_sim.experiments.replay_report import collect_replay

    label = {method_id(c.spec()): c.learner_label for c in config.cells}
    per_seed: dict = {}
    for cell, key in zip(config.cells, run.keys):  # learner by learner, the seeds inside: a seed's methods in order
        entry, examples = decode_method(run.records[key]["result"])
        entry["row"] = {**entry["row"], "method": cell.learner_label}
        if entry["row"].get("irl_from"):
            entry["row"]["irl_from"] = label[entry["row"]["irl_from"]]
        per_seed.setdefault(cell.seed, {"methods": {}, "examples": examples})["methods"][cell.learner_label] = entry
    return collect_replay(scene, proto, per_seed, [(c.learner_label, c.learner, c.learner_params)
                                                   for c in config.cells])


def _replay(settings: ReplaySettings, out: Path, say) -> tuple:
    """One scene (``settings.options.tracks``, ``.map``) through the sweep engine into ``out``; returns (result,
    scene, protocol), result and scene None with ``--dry-run``. Finished cells in ``out/cells/`` are reused: an
    interrupted replay resumes."""
    config = settings.config()  # validated before any work
    run, scene = _run_cells(config, settings, out, say)
    proto = settings.protocol()
    return (None if run is None else replay_results(config, run, scene, proto)), scene, proto


def _run_cells(config, settings: ReplaySettings, out: Path, say) -> tuple:
    """The cells of ``config`` (one recorded scene) into ``out``: (run, scene), both None with ``--dry-run``
    (which prints the counts). The scene is read here first: too few usable tracks fail before any cell, and
    ``--workers N`` > 1 forks N sweep workers that inherit it."""
    from pirl_sim.engine.executors import InlineExecutor, LocalExecutor
    from pirl_sim.engine.run import run_sweep
    from pirl_sim.experiments.recorded import load_scene, recorded_files, usable_tracks

    o = settings.options
    if o.dry_run:
        print_plan(config, out, f"{config.experiments[0].label} of {o.tracks}", code=True)
        return None, None
    files = recorded_files(config.cells[0].scenario_params)
    say(f"reading {len(files)} track files and {o.map} (dt {settings.dt:g} s, estimate {settings.estimate}, "
        f"selection {settings.selection})")
    scene = load_scene(dict(config.cells[0].scenario_params))  # the cells' scene (kept for them when inline)
    usable_tracks(scene, settings.protocol())
    with (InlineExecutor() if o.workers == 1 else LocalExecutor(o.workers, start_method="fork")) as executor:
        run = run_sweep(config, out, executor=executor, progress=not o.quiet, command=command_line("replay", []),
                        tables=False)
    run.check_failed(f"the {config.experiments[0].label}'s cells")
    say(f"{scene.n_converted} tracks converted (in {len(scene.trajectories)} pieces), {scene.n_selected_tracks} "
        f"selected; skipped {scene.skipped}; route repairs {scene.repairs}"
        + (f"; steps {scene.steps}" if scene.steps else ""))
    return run, scene


def run(args) -> int:
    """``pirl-sim replay``: 0, 2 for a bad option or unusable data, 130 when interrupted (finished cells are
    kept)."""
    from pirl_sim.experiments.replay_report import summarize, write_replay_results
    from pirl_sim.progress import reporter

    say = reporter(not args.quiet)
    try:
        options = ReplayOptions.from_args(args)
        if options.table is not None:
            return _run_table(options, say)
        settings = options.resolve()
        for note in settings.notes:
            say(note)
        if options.scan_horizon is not None:
            return _scan(settings, say)
        result, scene, _ = _replay(settings, options.out, say)
        if result is None:  # --dry-run
            return 0
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        return error(exc)
    except KeyboardInterrupt:
        return interrupted(args.out)
    write_replay_results(result, scene, options.out, command_line("replay", []))
    return finish(f"{options.out}/", table_text(summarize(result)), table_text(result["paired_ca"]))


def _scan(settings: ReplaySettings, say) -> int:
    """``--scan-horizon H1,H2,...``: the replay's scene and windows as the ``horizon-scan`` kind
    (`pirl_sim.experiments.horizon_scan`, one cell per split seed and H) instead of the replay."""
    from pirl_sim.experiments.horizon_scan import scan_rows, write_scan

    out = settings.options.out
    run, _ = _run_cells(settings.config(), settings, out, say)
    if run is None:  # --dry-run
        return 0
    table = write_scan(scan_rows([run.records[k]["result"] for k in run.keys]), out, command_line("replay", []))
    return finish(f"{out}/", table_text(table, digits=4))


def _run_table(options: ReplayOptions, say) -> int:
    """``replay --table ROOT``: every roundabout of ``roundabouts`` in turn (each through the sweep engine into
    ``out/NAME``), then the table (`pirl_sim.experiments.replay_table`); errors are the command's to report."""
    from pirl_sim.experiments.recorded import recorded_files
    from pirl_sim.experiments.replay_report import write_replay_results
    from pirl_sim.experiments.replay_table import table_row, write_table

    rows, command = [], command_line("replay", [])
    for name in options.roundabouts:
        t0 = time.perf_counter()
        o = dataclasses.replace(options, tracks=options.table / "recorded_trackfiles" / name,  # type: ignore[operator]
                                map=options.table / "maps" / f"{name}.osm")  # type: ignore[operator]
        if not o.map.is_file():  # type: ignore[union-attr]
            raise FileNotFoundError(f"no map {o.map}")
        result, scene, proto = _replay(o.resolve(), options.out / name, lambda m: say(f"{name}: {m}"))
        if result is None:  # --dry-run
            continue
        write_replay_results(result, scene, options.out / name, command)
        elapsed = time.perf_counter() - t0
        files = [f.name for f in recorded_files({"tracks": o.tracks, "files": o.files or 0})]
        rows.append(table_row(name, files, result, scene, proto, elapsed))
        say(f"{name}: done in {elapsed:.0f} s")
    return 0 if options.dry_run else finish(f"{options.out}/", write_table(rows, options.out, command))
