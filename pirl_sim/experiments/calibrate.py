"""A simulated population calibrated on recorded roundabout traffic.

`calibrate` reads INTERACTION track files on their Lanelet2 map with the simulated PIRL drivers' own model
(features ``speed_dev``, ``acc_sq``, ``jerk_sq``; their re-planning step and MPC horizon; their reference-path
smoothing), fits one weight vector per recorded car by the receding-horizon IRL on the steps where it neither
follows nor yields (`pirl_sim.receding`) under the desired speed (a_lat, v_max) of greatest likelihood, and fits
a Gaussian mixture to the log weights with the number of styles chosen by BIC. With ``interaction=True`` each car's
weights of ``headway`` and ``yielding`` (the simulated drivers who interact) are fitted too, on every step, and the
styles are a deconvolved mixture that integrates out the interaction weights a car's data do not determine.
`Calibration.scenario_toml` writes the result as a scenario TOML (``[drivers]`` and ``[population]``) that
``pirl-sim simulate`` runs: the simulated drivers' weights are then drawn from the fitted mixture and written to the
ground-truth sidecar, so they stay known. How each step works and what the figures mean: the documentation's
"Calibration" page.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence, cast

import numpy as np

from pirl_sim.receding import STEP_MASK, fit_receding
from pirl_sim.speed_fit import A_LAT_RANGE, V_MAX_RANGE, fit_desired_speed

__all__ = ["Calibration", "calibrate", "fit_styles", "fit_styles_deconvolved", "lognormal_moments", "MIN_TRACKS",
           "LOG_BOUNDS", "LOG_VAR_MAX", "ROADS", "FREE", "FREE_INTERACTING"]

#: fewest usable recorded cars a calibration fits a mixture to
MIN_TRACKS = 10
#: box on the log normalised weights of the per-car fits (a weight at its lower bound: the feature does not count)
LOG_BOUNDS = (-20.0, 20.0)
#: largest variance of a style's log weights that `Calibration.styles` moment-matches: the population's Gaussian
#: over the weights cannot hold a wider log-normal (its standard deviation grows as exp(variance))
LOG_VAR_MAX = 1.0
#: the desired speed of greatest likelihood (``desired_speed="likelihood"``) is searched on up to this many cars,
#: scoring every PROFILE_STRIDE-th free step, in at most PROFILE_EVALUATIONS fits
PROFILE_CARS = 12
PROFILE_STRIDE = 5
PROFILE_EVALUATIONS = 30
#: the features whose weights differ between drivers (``jerk_sq`` is the reference, 1 for everybody)
FREE = ("speed_dev", "acc_sq")
#: with ``interaction=True``: also the weights of the gaps to the vehicle ahead and to the point yielded at (the
#: ``interacting`` features of `pirl_sim.driving.roundabout_features`, the simulated drivers who interact)
FREE_INTERACTING = FREE + ("headway", "yielding")
_INTERACTION = FREE_INTERACTING[len(FREE):]
#: Where the written scenario drives: the recording's own roundabout (SUMO), or the simulators' parametric ring.
ROADS = ("map", "ring")


def lognormal_moments(mu: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (K,) and standard deviation (K,) of exp(X) for independent X_k ~ N(mu_k, var_k): the weights of a style
    whose log weights are Gaussian, as the population's Gaussian over the weights takes them (moment matching)."""
    mu, var = np.asarray(mu, float), np.asarray(var, float)
    mean = np.exp(mu + var / 2)
    return mean, mean * np.sqrt(np.expm1(var))


def fit_styles(log_weights: np.ndarray, max_styles: int = 4, seed: int = 0):
    """Gaussian mixtures (diagonal covariances) of 1 .. ``max_styles`` components fitted to ``log_weights`` (n, K);
    returns (the one of least BIC, {n_components: BIC})."""
    from sklearn.mixture import GaussianMixture

    x, fits, bic = np.asarray(log_weights, float), {}, {}
    for n in range(1, min(int(max_styles), len(x)) + 1):
        gmm = GaussianMixture(n, covariance_type="diag", reg_covar=1e-4, n_init=3, random_state=seed).fit(x)
        fits[n], bic[n] = gmm, float(gmm.bic(x))
    return fits[min(bic, key=bic.__getitem__)], bic


def fit_styles_deconvolved(log_weights: np.ndarray, log_se: np.ndarray, max_styles: int = 4, seed: int = 0):
    """Deconvolved Gaussian mixtures (`pirl_sim.deconvolution.extreme_deconvolution`) of 1 .. ``max_styles``
    components fitted to ``log_weights`` (n, K) measured with standard errors ``log_se`` (n, K) (a weight the data
    do not determine has `~pirl_sim.experiments.recovery_styles.UNKNOWN_SE`); returns (the one of least BIC,
    {n_components: BIC})."""
    from pirl_sim.deconvolution import extreme_deconvolution

    from .recovery_styles import N_INIT, diagonal_covariances

    x = np.asarray(log_weights, float)
    n, k = x.shape
    cov = diagonal_covariances(log_se)
    fits, bic = {}, {}
    for j in range(1, min(int(max_styles), n) + 1):
        mix = extreme_deconvolution(x, cov, j, rng=np.random.default_rng(seed), n_init=N_INIT)
        params = (j - 1) + j * k + j * k * (k + 1) // 2
        fits[j], bic[j] = mix, float(-2.0 * mix.log_likelihood + params * np.log(n))
    return fits[min(bic, key=bic.__getitem__)], bic


@dataclass(frozen=True)
class Calibration:
    """A population fitted to a recording (`calibrate`).

    Attributes
    ----------
    a_lat, v_max : float [m/s^2, m/s]     the desired speed's fitted lateral-acceleration limit and speed cap
    horizon, dt : int, float [steps, s]   the drivers' MPC horizon and re-planning step the weights were fitted with
    cars : tuple of (str, int)            (track file name, track id) of each fitted car
    log_weights, at_bound : array (n, K)   per car, log normalised weights of ``features``; at `LOG_BOUNDS`
    converged : array (n,) bool           the car's fit converged
    style_share : array (S,)              the mixture's component weights (sum 1)
    style_log_mean, style_log_var : array (S, K)   each style's Gaussian over the log weights (independent)
    bic : dict {n_styles: BIC}            of every mixture size tried; the least is kept
    depart_rate, n_cars, duration_s       cars per hour [veh/h], cars read, summed length of the files [s]
    map_path : str                        the Lanelet2 map the cars were read on
    route_counts : dict {route id: int}   cars per entry-to-exit route of the map (ids of
                                          `pirl_sim.scenarios.lanelet_graph.lanelet_paths`)
    features : tuple of str               the K fitted weights' features: `FREE`, or `FREE_INTERACTING`
    identified : array (n, K) bool or None   with `FREE_INTERACTING`: which cars' data determine each weight (the
                                          mixture integrates the others out)
    """

    a_lat: float
    v_max: float
    horizon: int
    dt: float
    cars: tuple
    log_weights: np.ndarray
    at_bound: np.ndarray
    converged: np.ndarray
    style_share: np.ndarray
    style_log_mean: np.ndarray
    style_log_var: np.ndarray
    bic: dict = field(default_factory=dict)
    depart_rate: float = math.nan
    n_cars: int = 0
    duration_s: float = math.nan
    map_path: str = ""
    route_counts: dict = field(default_factory=dict)
    features: tuple = FREE
    identified: np.ndarray | None = None

    def __post_init__(self) -> None:
        if tuple(self.features) not in (FREE, FREE_INTERACTING):
            raise ValueError(f"features must be {FREE} or {FREE_INTERACTING}, got {self.features!r}")
        n, s, k = len(self.log_weights), len(self.style_share), len(self.features)
        if len(self.cars) != n or np.shape(self.log_weights) != (n, k) or np.shape(self.at_bound) != (n, k):
            raise ValueError(f"cars, log_weights and at_bound must be as many as the cars ({n}), over {k} features")
        if np.shape(self.style_log_mean) != (s, k) or np.shape(self.style_log_var) != (s, k):
            raise ValueError(f"style_log_mean and style_log_var must hold {s} styles over {k} features")
        if not np.all(np.isfinite(self.log_weights)):
            raise ValueError("log_weights must be finite")
        if self.identified is not None and np.shape(self.identified) != (n, k):
            raise ValueError(f"identified must be None or of shape ({n}, {k}), got {np.shape(self.identified)}")

    @property
    def n_styles(self) -> int:
        """S, the number of styles the BIC chose."""
        return len(self.style_share)

    def styles(self) -> list[dict]:
        """Each style as a population's style table: name, weight, mean and std over the weights (moment-matched
        to the style's log-normal, `lognormal_moments`, its log variance capped at `LOG_VAR_MAX` and its mean and
        standard deviation at the population's largest value, `pirl_sim.population.STYLE_VALUE_MAX`), in order of
        decreasing share."""
        from pirl_sim.population import STYLE_VALUE_MAX

        order = np.argsort(-self.style_share, kind="stable")
        means, stds = lognormal_moments(self.style_log_mean[order], np.minimum(self.style_log_var[order], LOG_VAR_MAX))
        scale = np.minimum(1.0, STYLE_VALUE_MAX / np.maximum(means, stds))  # a log-normal shifted down to fit
        means, stds = means * scale, stds * scale
        return [{"name": f"calibrated {n + 1}", "weight": float(self.style_share[i]),
                 "mean": {f: float(m) for f, m in zip(self.features, mean)},
                 "std": {f: float(x) for f, x in zip(self.features, std)}}
                for n, (i, mean, std) in enumerate(zip(order, means, stds))]

    def population(self, n_vehicles: int = 80, background_share: float = 0.0):
        """The calibrated `~pirl_sim.scenarios.population_config.PopulationConfig`: its styles, departures at the
        recorded rate (Poisson), ``n_vehicles`` of which ``background_share`` driven by the simulator's model."""
        from pirl_sim.scenarios.population_config import population_from_dict

        return population_from_dict({"n_vehicles": n_vehicles, "depart_interval": 3600.0 / self.depart_rate,
                                     "arrivals": "poisson", "background_share": background_share,
                                     "control_noise": 0.0, "styles": self.styles()}, source="calibrated population")

    def scenario_toml(self, source: str = "", n_vehicles: int = 80, background_share: float = 0.0, *,
                      road: str = "map") -> str:
        """A scenario TOML (``[drivers]``: the fitted desired speed, insertion at its cap, the fit's horizon;
        ``[population]``) that ``pirl-sim simulate`` reads; comments give the figures. ``road="map"``: the
        recording's own roundabout, in SUMO or highway-env (``lanelet_map``, ``[route_weights]`` as the recorded
        cars' routes); ``"ring"``: the simulators' parametric ring."""
        if road not in ROADS:
            raise ValueError(f"road must be one of {ROADS}, got {road!r}")
        if road == "map" and not (self.map_path and self.route_counts):
            raise ValueError("road='map' needs the calibration's map_path and route_counts")
        pop = self.population(n_vehicles, background_share).to_dict()
        capped = int((self.style_log_var > LOG_VAR_MAX).any(axis=1).sum())
        lines = [f"# pirl_sim population calibrated on {source or 'a recording'}: {self.n_cars} cars, "
                 f"{len(self.log_weights)} fitted, {self.duration_s / 60:.1f} min recorded",
                 f"# styles chosen by BIC over 1..{max(self.bic)} components: "
                 + ", ".join(f"{n}: {b:.1f}" for n, b in sorted(self.bic.items())),
                 "# log weights at their bound: " + ", ".join(f"{f} {b:.0%}" for f, b in zip(self.features,
                                                                                           self.at_bound.mean(axis=0)))
                 + f"; converged fits {self.converged.mean():.0%}; styles "
                 f"whose log variance was capped at {LOG_VAR_MAX:g}: {capped}"]
        if self.identified is not None:
            lines.append("# cars whose data determine the weight: " + ", ".join(
                f"{f} {int(c)}" for f, c in zip(self.features, self.identified.sum(axis=0))))
        lines.append("")
        if road == "map":
            lines += [f"lanelet_map = {_toml(str(Path(self.map_path).resolve()))}   # SUMO and highway-env on this roundabout", ""]
        lines += ["[drivers]", f"horizon = {self.horizon}",
                 f"a_lat = {self.a_lat!r}   # [m/s^2] the desired speed's lateral-acceleration limit",
                 f"v_max = {self.v_max!r}   # [m/s] and speed cap",
                 f"depart_speed = {self.v_max!r}   # [m/s] at insertion: the speed cap", "", "[population]"]
        lines += [f"{k} = {_toml(pop[k])}" for k in ("n_vehicles", "depart_interval", "arrivals", "background_share",
                                                         "control_noise")]
        for style, order in zip(pop["styles"], np.argsort(-self.style_share, kind="stable")):
            mu, sd = self.style_log_mean[order], np.sqrt(self.style_log_var[order])
            lines += ["", "[[population.styles]]",
                      "# log weights: " + ", ".join(f"{f} {m:.3g} +- {s:.3g}" for f, m, s in zip(self.features, mu,
                                                                                                 sd))]
            lines += [f"{k} = {_toml(v)}" for k, v in style.items()]
        if road == "map":
            lines += ["", "[route_weights]   # recorded cars per route"]
            lines += [f"{k} = {n}" for k, n in sorted(self.route_counts.items())]
        return "\n".join(lines) + "\n"


def _toml(v) -> str:
    """A scalar or (nested) inline table as TOML."""
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(float(v)) if isinstance(v, float) else str(v)


def _own_steps(trajectories) -> list:
    """Free-flow runs read with the `following` features, as trajectories of the drivers' own model ((s, v, a)
    states) whose step mask leaves out every step at which the car yields at a conflict point: the simulated
    drivers' cost knows neither a vehicle ahead nor a conflict, so only what it can explain is fitted."""
    from pirl_sim.trajectory import Trajectory

    out = []
    for t in trajectories:
        yielding = np.asarray(t.metadata["yielding"], dtype=bool)
        own = ~(yielding[:-1] | yielding[1:])
        if own.any():
            out.append(Trajectory(t.states[:, :3], t.controls, t.dt, dict(t.metadata, **{STEP_MASK: own})))
    return out


#: a style's interaction weight is its own when the cars that determine it weigh at least this much in the style
#: (summed probabilities of membership); else it is that of all cars that determine it (`_determined_styles`)
MIN_DETERMINED = 5.0


def _determined_styles(mix, log_w: np.ndarray, se: np.ndarray, known: np.ndarray, features: tuple):
    """(share (S,), log mean (S, K), log variance (S, K)) of a deconvolved mixture's styles, where a style whose
    members' data determine an interaction weight in fewer than `MIN_DETERMINED` cars takes that weight's mean and
    variance over all cars that determine it (a component's mean in a weight nobody in it shows is arbitrary).
    ValueError when no car's data determine an interaction weight."""
    from .recovery_styles import diagonal_covariances

    resp = mix.predict_proba(log_w, diagonal_covariances(se))
    mean, var = mix.means.copy(), np.diagonal(mix.covariances, axis1=1, axis2=2).copy()
    for j, f in enumerate(features):
        if f not in _INTERACTION:
            continue
        shown = log_w[known[:, j], j]
        if not len(shown):
            raise ValueError(f"no recorded car's data determine the {f} weight (none came near enough to what it "
                             "weighs often enough): calibrate without interaction weights")
        thin = resp[known[:, j]].sum(axis=0) < MIN_DETERMINED
        mean[thin, j], var[thin, j] = shown.mean(), shown.var()
    return mix.weights, mean, var


def _identified(model, demos: list, labels: np.ndarray, res, cols: list[int], horizon: int):
    """Which fitted log weights (n_cars, K) the cars' data determine, and the standard errors the mixture takes.
    ``speed_dev`` and ``acc_sq`` count as in `fit_styles` (a weight at its bound too: its feature does not count for
    the car), with their standard errors floored at `~pirl_sim.experiments.recovery_styles.SE_FLOOR`; an interaction
    weight only by the recovery study's rule (standard error <= `~pirl_sim.experiments.recovery.IDENTIFIED_SE` and
    at least `~pirl_sim.experiments.recovery.MIN_NEAR_STEPS` steps within reach of its obstacle,
    `~pirl_sim.experiments.recovery.near_steps`), the others get `~pirl_sim.experiments.recovery_styles.UNKNOWN_SE`."""
    from .recovery import IDENTIFIED_SE, MIN_NEAR_STEPS, near_steps
    from .recovery_styles import SE_FLOOR, UNKNOWN_SE, determined

    raw = np.asarray(res.log_se, float)[:, cols]
    se = np.where(np.isfinite(raw), np.maximum(raw, SE_FLOOR), SE_FLOOR)
    known = np.ones(se.shape, dtype=bool)
    for j, f in enumerate(model.features.names[c] for c in cols):
        if f in _INTERACTION:
            near = np.zeros(len(se), dtype=int)
            for t, g in zip(demos, labels):  # every step is the car's own (a recording shows no overrides)
                near[g] += near_steps(model, t, f, horizon)
            known[:, j] = determined(raw[:, j], near, identified_se=IDENTIFIED_SE, min_near_steps=MIN_NEAR_STEPS)
    return known, np.where(known, se, UNKNOWN_SE)


def _most_likely_speed(model_at, demos, labels, start, horizon: int, say) -> tuple[float, float]:
    """(a_lat, v_max) of least summed receding-horizon negative log-likelihood of up to `PROFILE_CARS` evenly
    chosen cars (every `PROFILE_STRIDE`-th step), each car's weights fitted anew at every point (warm-started):
    Nelder-Mead over the log parameters from ``start``, within `pirl_sim.speed_fit`'s ranges."""
    from scipy.optimize import minimize

    n_cars = int(labels.max()) + 1
    chosen = np.unique(np.linspace(0, n_cars - 1, min(PROFILE_CARS, n_cars)).round().astype(int))
    keep = np.isin(labels, chosen)
    sub, sub_labels = [t for t, k in zip(demos, keep) if k], np.searchsorted(chosen, labels[keep])
    lo, hi = np.log([A_LAT_RANGE[0], V_MAX_RANGE[0]]), np.log([A_LAT_RANGE[1], V_MAX_RANGE[1]])
    warm: dict[str, np.ndarray | None] = {"init": None}

    def nll(x: np.ndarray) -> float:
        res = fit_receding(model_at(*np.exp(np.clip(x, lo, hi))), sub, sub_labels, horizon=horizon,
                           stride=PROFILE_STRIDE, log_bounds=LOG_BOUNDS, init=warm["init"])
        warm["init"] = res.normalized
        return float(res.neg_log_likelihood.sum())

    say(f"desired speed of greatest likelihood of {len(chosen)} cars, from a_lat {start[0]:.3g} m/s^2, "
        f"v_max {start[1]:.3g} m/s (the speeds' fit)")
    x0 = np.clip(np.log(start), lo, hi)
    out = minimize(nll, x0, method="Nelder-Mead",
                   options={"xatol": 0.01, "fatol": 0.5, "maxfev": PROFILE_EVALUATIONS,
                            "initial_simplex": np.array([x0, x0 + [0.1, 0.0], x0 + [0.0, 0.05]])})
    return cast(tuple[float, float], tuple(float(v) for v in np.exp(np.clip(out.x, lo, hi))))


def _recorded_demand(files: Sequence[Path], lmap) -> tuple[float, dict[str, int]]:
    """Summed time span [s] of the track files, and their cars per entry-to-exit route of the map
    (`pirl_sim.scenarios.demand.demand_from_tracks`), each file read once."""
    from pirl_sim.io.interaction import read_tracks
    from pirl_sim.scenarios.demand import demand_from_tracks
    from pirl_sim.scenarios.lanelet_graph import lanelet_paths

    routes = {path: rid for rid, path in lanelet_paths(lmap)}
    duration, counts = 0.0, Counter()  # type: ignore[var-annotated]
    for f in files:
        tracks = read_tracks(f)
        stamps = tracks["timestamp_ms"].to_numpy()
        duration += (stamps.max() - stamps.min()) / 1000.0 if len(stamps) else 0.0
        cars = tracks[tracks["agent_type"] == "car"]
        if len(cars):
            counts.update(routes[d.route] for d in demand_from_tracks(cars, lmap, list(routes)).departures)
    return duration, dict(sorted(counts.items()))


def calibrate(track_files: Sequence[str | Path], map_path: str | Path, *, max_styles: int = 4, stride: int = 2,
              seed: int = 0, drivers=None, desired_speed="likelihood", min_tracks: int = MIN_TRACKS,
              interaction: bool = False, progress: Callable[[str], None] | None = None) -> Calibration:
    """Fit a population of PIRL drivers to recorded cars (module doc).

    Parameters
    ----------
    track_files, map_path : paths   ``vehicle_tracks_*.csv`` files of one roundabout; its Lanelet2 map
    max_styles, stride : int      largest number of styles the BIC chooses; score every stride-th step
    seed : int                    of the mixture's EM initialisation
    drivers : MpcDriverConfig, optional   the simulated drivers whose model is fitted (default: the simulators')
    desired_speed : "likelihood", "speeds" or (float, float)   a_lat [m/s^2], v_max [m/s]: of greatest likelihood
                                  (`PROFILE_CARS` cars), fitted to the speeds alone, or given ("Calibration" page)
    min_tracks, progress : int, callable(str)   fewest usable cars (>= 2); told what is being done (optional)
    interaction : bool            also fit the weights of ``headway`` and ``yielding`` (`FREE_INTERACTING`), on every
                                  step of each car with the vehicle ahead and the point it yields at as recorded; the
                                  written population's drivers then interact ("Calibration" page)

    Raises
    ------
    ValueError    a bad parameter; no track file; a map without a roundabout; fewer than ``min_tracks`` usable cars
                  (e.g. tracks off the map)
    """
    from pirl_sim.driving import PathDriverModel, SpeedProfile, roundabout_features
    from pirl_sim.dynamics import following, longitudinal
    from pirl_sim.io.lanelet2_map import load_map
    from pirl_sim.scenarios.replay import load_replay, track_key
    from pirl_sim.scenarios.scenario_config import MpcDriverConfig
    from pirl_sim.scenarios.lanelet_graph import ring_lanelets
    from pirl_sim.validation import int_at_least

    for name, value, low in (("max_styles", max_styles, 1), ("stride", stride, 1), ("min_tracks", min_tracks, 2)):
        int_at_least(name, value, low)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not isinstance(interaction, bool):
        raise TypeError(f"interaction must be True or False, got {interaction!r}")
    if not (isinstance(desired_speed, str) and desired_speed in ("likelihood", "speeds")):
        pair = np.asarray(desired_speed, dtype=float) if not isinstance(desired_speed, str) else np.array([])
        if pair.shape != (2,) or not np.all(np.isfinite(pair)) or np.any(pair <= 0):
            raise ValueError(f"desired_speed must be 'likelihood', 'speeds' or (a_lat, v_max), two numbers > 0 "
                             f"[m/s^2, m/s], got {desired_speed!r}")
        desired_speed = tuple(float(x) for x in pair)
    drivers = MpcDriverConfig() if drivers is None else drivers
    if not isinstance(drivers, MpcDriverConfig):
        raise TypeError(f"drivers must be an MpcDriverConfig, got {type(drivers).__name__}")
    files = [Path(f) for f in track_files]
    if not files:
        raise ValueError("calibrate needs at least one track file, got none")
    say = progress or (lambda _msg: None)
    dt = 0.1  # the simulated drivers re-plan every frame
    lmap = load_map(map_path)
    if not ring_lanelets(lmap):
        raise ValueError(f"map {map_path}: no roundabout (no lanelets form a cycle in its routing graph); calibrate "
                         "fits the drivers of a roundabout")
    say(f"reading {len(files)} track file(s) on {Path(map_path).name}")

    def read(features: str, selection: str):
        """The recorded cars read with ``features`` (``selection`` of `load_replay`)."""
        return load_replay(files, map_path, dt=dt, features=features, selection=selection, estimate="speeds",
                           smoothing=drivers.smoothing, speed_smoothing=drivers.speed_smoothing, max_steps=None)

    def cars(scene, demos: list) -> tuple[list, np.ndarray]:
        """The cars' keys (in order) and each trajectory's car, or the error for too few cars."""
        keys = list(dict.fromkeys(track_key(t) for t in demos))
        if len(keys) < min_tracks:
            raise ValueError(f"{len(keys)} usable car(s) in {len(files)} track file(s) (of {scene.n_tracks} read; "
                             f"skipped: {scene.skipped}): a mixture needs at least {min_tracks}; give more track "
                             "files or check that they were recorded on this map")
        index = {k: i for i, k in enumerate(keys)}
        return keys, np.array([index[track_key(t)] for t in demos])

    scene = read("following", "free")
    demos = _own_steps(scene.selected)
    keys, labels = cars(scene, demos)

    def model_at(a_lat: float, v_max: float, on=scene, kind: str = "paper"):
        """The drivers' model on the paths of scene ``on`` under the desired speed (a_lat, v_max)."""
        profile = SpeedProfile(on.profile_path, a_lat, v_max)  # on.profile_path: a CompositePath
        dynamics = following(dt, obstacles=2) if kind == "interacting" else longitudinal(dt)
        return PathDriverModel(dynamics, roundabout_features(profile, kind), on.model.bounds, path=on.model.path)

    if isinstance(desired_speed, str):
        fit = fit_desired_speed(scene.curvature(np.concatenate([t.states[:, 0] for t in demos])),
                                np.concatenate([t.states[:, 1] for t in demos]))
        desired_speed = (fit.a_lat, fit.v_max) if desired_speed == "speeds" else _most_likely_speed(
            model_at, demos, labels, (fit.a_lat, fit.v_max), drivers.horizon, say)
    a_lat, v_max = desired_speed
    features = FREE_INTERACTING if interaction else FREE
    model = model_at(a_lat, v_max)
    if interaction:  # every step, with the vehicle ahead and the point yielded at in the cost
        say("reading the track files again with the vehicle ahead and the conflict points (every step)")
        every = read("interacting", "all")
        demos = list(every.selected)
        keys, labels = cars(every, demos)
        model = model_at(a_lat, v_max, every, "interacting")
    say(f"desired speed: a_lat {a_lat:.3g} m/s^2, v_max {v_max:.3g} m/s; fitting the weights of {len(keys)} cars "
        f"(horizon {drivers.horizon} steps of {dt:g} s)")
    res = fit_receding(model, demos, labels, horizon=drivers.horizon, stride=stride, log_bounds=LOG_BOUNDS)
    cols = [list(model.features.names).index(f) for f in features]
    log_w = np.log(res.normalized[:, cols])
    known = None
    if interaction:  # a mixture that integrates out the weights a car's data do not determine
        known, se = _identified(model, demos, labels, res, cols, drivers.horizon)
        gmm, bic = fit_styles_deconvolved(log_w, se, max_styles, seed)
        share, mean, var = _determined_styles(gmm, log_w, se, known, features)
    else:
        gmm, bic = fit_styles(log_w, max_styles, seed)
        share, mean, var = gmm.weights_, gmm.means_, gmm.covariances_
    say(f"{len(share)} style(s) by BIC")
    duration, route_counts = _recorded_demand(files, lmap)
    if not duration > 0:
        raise ValueError(f"the track files span {duration:g} s: no departure rate can be read from them")
    return Calibration(a_lat=float(a_lat), v_max=float(v_max), horizon=drivers.horizon, dt=dt,
                       cars=tuple((Path(f).name, int(i)) for f, i in keys), log_weights=log_w,
                       at_bound=res.at_bound[:, cols], converged=np.asarray(res.converged), style_share=share,
                       style_log_mean=mean, style_log_var=var, bic=bic, identified=known,
                       depart_rate=3600.0 * scene.n_tracks / duration, n_cars=int(scene.n_tracks), duration_s=duration,
                       map_path=str(map_path), route_counts=route_counts, features=features)
