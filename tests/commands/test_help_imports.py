"""`--help` of every command answers without torch, Lightning, Stable-Baselines3, moderngl or the simulator's scipy
and osqp: a command's module holds its options and imports the heavy libraries in its run function, after parsing
(issue 62)."""

from __future__ import annotations

import json
import subprocess
import sys

from vision_rl.commands.main import COMMANDS

HEAVY = ("torch", "lightning", "stable_baselines3", "moderngl", "scipy.interpolate", "osqp")

# In a fresh interpreter: import one command module, list the heavy libraries loaded, then parse --help of each of
# its commands and list them again.
_SCRIPT = """
import contextlib, importlib, io, json, sys
module, names = sys.argv[1], sys.argv[2:]
heavy = {heavy!r}
def loaded():
    return sorted(m for m in heavy if m in sys.modules)
importlib.import_module(module)
found = {{module: loaded()}}
from vision_rl.commands.main import main
for name in names:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main([*name.split(), "--help"])
    found[name + " --help"] = loaded()
print(json.dumps(found))
"""


def test_no_command_module_or_help_imports_a_heavy_library():
    by_module: dict[str, list[str]] = {}
    for name, command in COMMANDS.items():
        by_module.setdefault(command.module, []).append(name)
    script = _SCRIPT.format(heavy=HEAVY)
    pending = list(by_module.items())
    found: dict[str, list[str]] = {}
    while pending:  # two interpreters at a time
        batch, pending = pending[:2], pending[2:]
        runs = [
            subprocess.Popen([sys.executable, "-c", script, module, *names], stdout=subprocess.PIPE, text=True)
            for module, names in batch
        ]
        for run in runs:
            out, _ = run.communicate(timeout=120)
            assert run.returncode == 0, run.args[3]
            found.update(json.loads(out.strip().splitlines()[-1]))
    assert {f"{name} --help" for name in COMMANDS} <= set(found)
    heavy = {what: libraries for what, libraries in found.items() if libraries}
    assert not heavy, f"imported before parsing: {heavy}"
