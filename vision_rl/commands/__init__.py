"""The command layer: the only package that parses arguments, builds configs from them, shows progress and prints.

Library packages never import it. Every command is an options dataclass (a docstring per field: the option's
help) and a ``run(options) -> exit code`` function, both imported only when that command runs, so
`vision-rl tracks` never loads torch. Figures go to stdout through :func:`vision_rl.commands.output.emit`: text, or
one JSON document with ``--json``.

How to add a command:

1. Write ``vision_rl/commands/<name>.py`` with a frozen dataclass ``<Name>Options`` and ``run_<name>(opts) -> int``.
   Where a library config exists, subclass it and add only command options (``json``, ``progress``...); else
   declare the fields. Give every field an attribute docstring (the string right after it): it is the ``--help``.
2. In ``run_<name>``, call the library function by keyword, pass a progress callback if it takes one (bars come
   from :func:`vision_rl.commands.output.progress_bar`), and print only through ``emit(result, opts.json, lines)``.
3. Register it in :data:`vision_rl.commands.main.COMMANDS` (a two-word name such as ``bench render`` joins the
   ``bench`` group); for a console-script alias add an entry to ``[project.scripts]`` in pyproject.toml.
4. Test it in ``tests/commands/``.
"""
