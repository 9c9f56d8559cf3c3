"""The paper's published numbers, transcribed as printed (units in the names; down negative).

Jia et al., "Research on Landing Dynamics of Foot-High Projectile Body for High-Precision
Microgravity Simulation System", Actuators 2024, 13(9), 361. Tables 3-6 give, per test condition,
the paper's simulation ("theoretical") and its experiment ("actual"); the relative errors it
prints are |actual - theoretical| / theoretical.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperCondition:
    """One test condition of Tables 2-6."""

    external_load_g: tuple[float, ...]  # Table 2 (condition 3: 50 g, then 1050 g in all)
    descent_height_mm: float  # Table 2
    table2_descent_accel_mm_s2: tuple[float, ...]  # Table 2, the target microgravity
    simulated_max_deformation_mm: float  # Table 3 = Table 5 "theoretical"
    simulated_descent_accel_mm_s2: tuple[float, ...]  # Table 3 = Table 4 "theoretical"
    simulated_collision_accel_mm_s2: float  # Table 6 "theoretical"
    table3_collision_accel_mm_s2: float  # Table 3 (130.20 for condition 1, where Table 6 prints 131.20)
    measured_descent_accel_mm_s2: tuple[float, ...]  # Table 4 "actual"
    measured_max_deformation_mm: float  # Table 5 "actual"
    measured_collision_accel_mm_s2: float  # Table 6 "actual"
    printed_descent_error_pct: tuple[float, ...]  # Table 4
    printed_deformation_error_pct: float  # Table 5
    printed_collision_error_pct: float  # Table 6
    simulated_x_change_at_collision_um: float  # Section 3.2
    measured_compensation_accuracy_pct: float  # Section 4.2


PUBLISHED: dict[int, PaperCondition] = {
    1: PaperCondition(
        external_load_g=(490.0,),
        descent_height_mm=90.0,
        table2_descent_accel_mm_s2=(-7.73,),
        simulated_max_deformation_mm=9.20,
        simulated_descent_accel_mm_s2=(-7.84,),
        simulated_collision_accel_mm_s2=131.20,
        table3_collision_accel_mm_s2=130.20,
        measured_descent_accel_mm_s2=(-7.61,),
        measured_max_deformation_mm=9.14,
        measured_collision_accel_mm_s2=123.90,
        printed_descent_error_pct=(2.90,),
        printed_deformation_error_pct=0.65,
        printed_collision_error_pct=5.56,
        simulated_x_change_at_collision_um=0.2,
        measured_compensation_accuracy_pct=97.1,
    ),
    2: PaperCondition(
        external_load_g=(1000.0,),
        descent_height_mm=90.0,
        table2_descent_accel_mm_s2=(-15.78,),
        simulated_max_deformation_mm=13.10,
        simulated_descent_accel_mm_s2=(-16.01,),
        simulated_collision_accel_mm_s2=187.20,
        table3_collision_accel_mm_s2=187.20,
        measured_descent_accel_mm_s2=(-15.96,),
        measured_max_deformation_mm=13.58,
        measured_collision_accel_mm_s2=184.14,
        printed_descent_error_pct=(0.30,),
        printed_deformation_error_pct=3.66,
        printed_collision_error_pct=1.63,
        simulated_x_change_at_collision_um=0.3,
        measured_compensation_accuracy_pct=99.7,
    ),
    3: PaperCondition(
        external_load_g=(50.0, 1050.0),
        descent_height_mm=55.0,
        table2_descent_accel_mm_s2=(-0.79, -16.56),
        simulated_max_deformation_mm=7.37,
        simulated_descent_accel_mm_s2=(-0.8, -16.81),
        simulated_collision_accel_mm_s2=103.65,
        table3_collision_accel_mm_s2=103.65,
        measured_descent_accel_mm_s2=(-0.38, -16.1),
        measured_max_deformation_mm=7.71,
        measured_collision_accel_mm_s2=113.24,
        printed_descent_error_pct=(52.50, 4.22),
        printed_deformation_error_pct=4.61,
        printed_collision_error_pct=9.25,
        simulated_x_change_at_collision_um=0.15,
        measured_compensation_accuracy_pct=95.78,
    ),
}

#: Section 4.2: condition 3's first stage fell at -0.38 mm/s^2, "resulting in a lag of 3.9 s between
#: the displacement and acceleration curves", s.
FIFTY_GRAM_LAG_S = 3.9
#: Section 3.2: "the gravitational error with the ideal microgravity environment is only 1.4%".
SIMULATED_FREE_FALL_ERROR_PCT = 1.4
#: The paper's largest model-versus-experiment errors (Tables 5 and 6, condition 3).
WORST_DEFORMATION_ERROR_PCT = 4.61
WORST_COLLISION_ERROR_PCT = 9.25


def experiment_relative_error_pct(model: float, experiment: float) -> float:
    """Signed (model - experiment) / experiment in %, the convention of this project's residuals."""
    return 100.0 * (model - experiment) / experiment
