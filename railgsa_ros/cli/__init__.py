"""The ``railgsa`` command line: one module per subcommand, each with ``register`` and ``run``.

A subcommand module defines ``register(subparsers)`` (adds its parser and
``set_defaults(func=run)``) and ``run(args) -> int``; ``railgsa_ros.cli.main`` finds the modules
by themselves. Modules import heavy packages inside ``run`` so that ``railgsa --help`` stays fast.
"""
