"""The paper: its transcribed numbers, the pad calibration and the reproduction report."""
