import subprocess
import sys

import pytest

from mcvar import __version__
from mcvar.cli import build_parser, main


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out
    for cmd in ("samplers", "render", "converge", "demo"):
        with pytest.raises(SystemExit) as exc:
            main([cmd, "--help"])
        assert exc.value.code == 0
        assert "usage: mcvar " + cmd in capsys.readouterr().out


def test_python_dash_m_runs_the_same_cli():
    out = subprocess.run([sys.executable, "-m", "mcvar", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"mcvar {__version__}"


def test_converge_parses_lists():
    args = build_parser().parse_args(["converge", "cornell", "--integrators", "path,direct_mis",
                                      "--spp", "1,2,4", "--samplers", "random,sobol"])
    assert args.methods == ["path", "direct_mis"] and args.spp == [1, 2, 4]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["converge", "cornell", "--spp", "1,x"])
