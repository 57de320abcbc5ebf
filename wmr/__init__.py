"""wmr: adaptive trajectory tracking of wheeled mobile robots."""

__version__ = "0.1.0"
