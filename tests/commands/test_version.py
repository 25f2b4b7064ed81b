"""`vision-rl --version`: the installed distribution's version, exit 0."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import pytest

from vision_rl.commands.main import main
from vision_rl.files import package_version


def test_version_prints_the_distributions_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"vision-rl {package_version()}"
    try:
        installed = version("vision-rl-racing")
    except PackageNotFoundError:
        pytest.skip("vision-rl-racing is not installed here (run from a source tree)")
    assert out == f"vision-rl {installed}"
