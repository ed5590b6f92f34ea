"""Sub-commands of the ``flexstab`` command-line tool (one module each).

Each module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a callable ``(args) -> int`` (the exit code).
"""
