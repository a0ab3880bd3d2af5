"""The paper's reported numbers (CARLA, section "Experiments"), in one place: the avoid summary and the
report both read them, so a number is never quoted twice with two values.

Every η̂1 the paper reports carries ± THETA, its Chernoff precision at γ = 0.05 (738 runs).
"""

from uqdrive.records import record

THETA = 0.05
GAMMA = 0.05
DROPOUT_RATES = (0.1, 0.08, 0.08)  # MCD's concrete-dropout rates of the three head layers

# Offline safety at the roundabout (Figure offline_safety_main), η1 over the weathers clear noon, afternoon, rain.
OFFLINE_ALL_WEATHERS = {"hmc": 0.766, "vi": 0.91, "mcd": 0.58}
OFFLINE_WITHOUT_RAIN = {"mcd": 0.87}
OFFLINE_TRAINING_WEATHER = {"mcd": 1.0}  # "the only method to achieve a perfect safety score"

# Real-time collision avoidance (Figures warnings, coll_avoid_main), reported for VI only.
AVOID_METHOD = "vi"
AVOID_UNKNOWN_OFF = 0.0  # unknown conditions, no warning system
AVOID_UNKNOWN_ON = 0.90  # unknown conditions, warnings δ1 = 0.7, δ2 = 0.6, τ = 0.45
AVOID_KNOWN_ON = 1.0  # the training condition with warnings: safe ...
AVOID_KNOWN_AUTONOMY = 1.0  # ... and "full autonomy (i.e. never stops to ask for user to assume control)"
WARNING_THRESHOLDS = {"delta1": 0.7, "delta2": 0.6, "tau": 0.45}


@record
class OfflineNumbers:
    """The offline-safety η1 the paper reports, by method."""

    all_weathers: dict[str, float]
    without_rain: dict[str, float]
    training_weather: dict[str, float]


@record
class AvoidNumbers:
    """Collision avoidance as the paper reports it (for ``method`` only), with the warning thresholds it used."""

    method: str
    unknown_off: float
    unknown_on: float
    known_on: float
    known_autonomy: float
    thresholds: dict[str, float]


@record
class PaperNumbers:
    """Everything above as one record (metrics/avoid.json carries it beside our numbers)."""

    theta: float
    gamma: float
    dropout_rates: list[float]
    offline: OfflineNumbers
    avoid: AvoidNumbers


def numbers() -> PaperNumbers:
    return PaperNumbers(
        THETA,
        GAMMA,
        list(DROPOUT_RATES),
        OfflineNumbers(OFFLINE_ALL_WEATHERS, OFFLINE_WITHOUT_RAIN, OFFLINE_TRAINING_WEATHER),
        AvoidNumbers(
            AVOID_METHOD, AVOID_UNKNOWN_OFF, AVOID_UNKNOWN_ON, AVOID_KNOWN_ON, AVOID_KNOWN_AUTONOMY, WARNING_THRESHOLDS
        ),
    )
