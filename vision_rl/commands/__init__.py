"""The command layer: the only package that parses arguments, builds configs from them, shows progress and prints.
Library packages never import it. Every command is an options dataclass (a docstring per field: the option's help)
and a ``run(options) -> exit code`` function, both imported only when that command runs.

How to add a command: docs/notes/commands.md.
"""
