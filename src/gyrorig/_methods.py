"""The simulator's method names, importable without the physics (the command line lists them)."""

__all__ = ["METHODS"]

#: method name -> (formulation, scipy solver)
METHODS: dict[str, tuple[str, str]] = {
    "gyro": ("axis", "DOP853-jit"),
    "gyro-scipy": ("axis", "DOP853"),
    "gyro-radau": ("axis", "Radau"),
    "DOP853-jit": ("body", "DOP853-jit"),
    "phasor": ("phasor", "DOP853"),
    "RK23": ("body", "RK23"),
    "RK45": ("body", "RK45"),
    "DOP853": ("body", "DOP853"),
    "Radau": ("body", "Radau"),
    "BDF": ("body", "BDF"),
    "LSODA": ("body", "LSODA"),
}
