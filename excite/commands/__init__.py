"""The subcommands of ``excite``: one module each, with ``add_parser(subparsers)`` and
``run(args) -> exit status``; :mod:`excite.cli` wires them together. Heavy layers are imported
inside ``run`` so that ``excite --version`` and the core commands stay light.

What the subcommands share: :mod:`~excite.commands.args` (argument types and value checks),
:mod:`~excite.commands.options` (option groups of several commands, each default defined once),
:mod:`~excite.commands.logs` (the log options of calibrate, segment and validate, turned into
:class:`excite.logs.inputs.LogOptions`),
:mod:`~excite.commands.parser` (the parser: one-line errors, help texts naming registries) and
:mod:`~excite.commands.exit_status` (the exit statuses).
"""
