"""Every numerical choice of the noise study (``ehss noise``): sensor sets, grids, thresholds of its rules."""

from __future__ import annotations

from dataclasses import dataclass

from ehss_gym.core.scenarios import DEFAULT_DISTRIBUTION

NS = (2, 4, 6)
TASKS = ("velocity", "position")
ENV_NOISE_MAX = DEFAULT_DISTRIBUTION.noise_std_max  # (x1 [rad], x2 [rad/s], x3 [Pa], x4 [m^2]): the env's largest

# A realistic sensor set of an EHSS test bench, each channel as white noise of the stated std (a quantiser of
# step q is read as std q / sqrt(12)). These are typical catalogue figures, assumptions stated here, not a
# measured rig:
# - x1, position: a 17-bit absolute encoder, q = 2 pi / 2^17 = 4.8e-5 rad -> 1.4e-5 rad;
# - x2, velocity: a DC tachometer on a 16-bit ADC over +-10 rad/s (q = 3.1e-4 rad/s -> 8.8e-5 rad/s) with an
#   analog noise floor of the same size -> 1.2e-4 rad/s (root sum of squares);
# - x3, load pressure: the difference of two 0-10 MPa transducers (the standard range above P_s = 9 MPa), each
#   with a noise floor of 0.05 % of full scale (5e3 Pa; well inside their +-0.25 % accuracy) -> 7.1e3 Pa;
# - x4, valve opening: the spool LVDT at 0.05 % of the full opening K * 10 mA = 8e-6 m^2 -> 4e-9 m^2.
# Against the env's largest noise (ENV_NOISE_MAX) that is 1.4x, 1.2x, 3.5x and 40x.
REALISTIC = (1.4e-5, 1.2e-4, 7.1e3, 4e-9)
REALISTIC_SOURCES = ("17-bit encoder", "tachometer, 16-bit ADC", "two 0-10 MPa transducers", "spool LVDT")


@dataclass(frozen=True)
class NoiseStudyConfig:
    """The noise study's choices. ``full()`` is the default run, ``quick_config()`` the CI smoke run.

    Attributes:
        quick: True for the smoke configuration (numbers not meaningful).
        levels: noise levels, multiples of the env's largest noise (ENV_NOISE_MAX) on all four channels.
        realistic: the realistic sensor set (std of x1..x4), an extra row of every map.
        estimators: (label, Scenario fields) of the estimators compared.
        laws: (label, Scenario fields) of the laws compared; "lin-sontag" gets its own sigma (stage_ls_sigma).
        layer_gain: the adaptive boundary layer's gain: the layer holds +-3 noise std of s, 99.7 % of a
            Gaussian's samples, so sign(s) stops flipping on noise alone.
        grid_episodes: randomised training scenarios per map cell (seeds 0, 1, ...).
        final_episodes: randomised scenarios of the final check (seeds 0, 1, ...).
        heldout_episodes: held-out scenarios of the final check (the evaluation suite's).
        ls_sigmas: per task, the sigmas the Lin-Sontag rule chooses from.
        ref_accels: the reference shaper's acceleration bounds [rad/s^2] the start-up rule chooses from.
        lost_rms: an episode has lost track if the RMS error of some 0.1 s window after 0.2 s exceeds this.
        max_lost: largest lost share a chosen setting may have (the reproduction study's robustness rule).
        track_tol: the estimator/law rule keeps pairs whose quiet RMSE and friction peak are within this factor
            of the best admissible pair's.
        max_sat: largest mean saturation an admissible pair may have.
        paper_t_end: duration of the paper run of the n comparison [s].
        bias_mismatch: the relative plant-parameter deviations of the bias check (+-20 %: the env's range).
        bias_t_end: duration of the bias runs [s].
    """

    quick: bool = False
    levels: tuple = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0)
    realistic: tuple = REALISTIC
    estimators: tuple = (
        ("svf", (("estimator", "foh"),)),
        ("svf-300", (("estimator", "foh"), ("estimator_hz", 300.0))),
        ("state", (("estimator", "state"),)),
        ("eso-200", (("estimator", "eso"), ("observer_hz", 200.0))),
        ("eso-1k", (("estimator", "eso"), ("observer_hz", 1000.0))),
    )
    laws: tuple = (("sontag", ()), ("sontag+al", (("layer_gain", 3.0),)), ("lin-sontag", (("law", "lin-sontag"),)),
                   ("lin-sontag+al", (("law", "lin-sontag"), ("layer_gain", 3.0))))
    layer_gain: float = 3.0
    grid_episodes: int = 16
    final_episodes: int = 100
    heldout_episodes: int = 48
    ls_sigmas: tuple = (("velocity", (1e5, 3e5, 1e6, 3e6, 1e7)), ("position", (1e6, 3e6, 1e7, 3e7, 1e8)))
    ref_accels: tuple = (100.0, 200.0, 300.0, 400.0)
    lost_rms: float = 0.3
    max_lost: float = 0.01
    track_tol: float = 2.0
    max_sat: float = 0.01
    paper_t_end: float = 20.0
    bias_mismatch: float = 0.2
    bias_t_end: float = 2.0

    @classmethod
    def full(cls) -> NoiseStudyConfig:
        return cls()

    @classmethod
    def quick_config(cls) -> NoiseStudyConfig:
        """Tiny grids: checks that the pipeline and the report render (seconds)."""
        return cls(quick=True, levels=(0.0, 1.0), grid_episodes=1, final_episodes=3, heldout_episodes=2,
                   ls_sigmas=(("velocity", (1e5, 1e6)), ("position", (1e6, 1e7))), ref_accels=(300.0,),
                   paper_t_end=0.5, bias_t_end=0.3)

    def sigmas_ls(self, task: str) -> tuple:
        return dict(self.ls_sigmas)[task]

    def noise_rows(self) -> list[tuple[str, tuple]]:
        """(label, noise std of x1..x4) of every map row: the levels, then the realistic set."""
        rows = [(f"{k:g}x", tuple(k * v for v in ENV_NOISE_MAX)) for k in self.levels]
        return rows + [("realistic", tuple(self.realistic))]
