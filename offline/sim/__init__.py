"""Simulation layer: the rover plant, actuators and sensors, closed-loop experiments (ch. 7.3)."""

__all__: list[str] = []
