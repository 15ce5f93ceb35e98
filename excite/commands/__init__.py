"""The subcommands of ``excite``: one module each, with ``add_parser(subparsers)`` and
``run(args) -> exit status``. :mod:`excite.cli` wires them together; heavy layers are imported
inside ``run`` so that ``excite --version`` and the core commands stay light."""
