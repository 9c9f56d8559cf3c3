"""What microg 0.1.0 reported, transcribed, so the report can show each new number beside it.

Source: ``docs/reproduction/report.json`` of microg 0.1.0 (commit 8948ba9): conditions 1-3 with
the PID (Kp 198.3 s^-1, Ki 20000 s^-2), every imperfection on, seed 0, Table 1's pad, a 0.5 ms
physics step. The fidelity review (0.2.0) found that several rested on numerical artifacts; the
report's "What changed" section explains each difference.
"""

from __future__ import annotations

#: Per condition: compensation error of each load stage (%), max |x| in free fall and during the
#: collision (um), peak pad deformation of the rig and of the ideal reference (mm).
RELEASE_0_1 = {
    1: {
        "compensation_error_pct": (-0.282,),
        "free_fall_excursion_um": 2.856,
        "collision_excursion_um": 8.168,
        "max_deformation_mm": (13.408, 13.405),
    },
    2: {
        "compensation_error_pct": (-0.283,),
        "free_fall_excursion_um": 3.251,
        "collision_excursion_um": 10.585,
        "max_deformation_mm": (19.769, 19.765),
    },
    3: {
        "compensation_error_pct": (-0.315, -0.289),
        "free_fall_excursion_um": 3.293,
        "collision_excursion_um": 6.978,
        "max_deformation_mm": (12.052, 12.051),
    },
}
#: The screw's continuous torque in 0.1.0 (the balancer in parallel with the QZS), N m.
SCREW_TORQUE_0_1_N_M = 51.5
#: The PID gains of 0.1.0 (Kp s^-1, Ki s^-2).
PID_GAINS_0_1 = (198.3, 20000.0)
