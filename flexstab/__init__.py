"""flexstab: Floquet stability analysis and Taguchi-tuned PD stability control
of time-periodic multibody systems (command-line tool and shared utilities)."""
__version__ = "0.1.0"
__all__ = ["__version__"]
