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


def test_converge_measures_a_user_renderer_by_module_function(tmp_path, monkeypatch, capsys):
    # the user's module lives in the current folder, as it would for `mcvar converge --target`
    import shutil
    from pathlib import Path as _Path

    shutil.copy(_Path(__file__).with_name("toy_renderer.py"), tmp_path / "my_toy_renderer.py")
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    code = main(["converge", "--target", "my_toy_renderer:evaluate", "--replicates", "6", "--workers", "1",
                 "--seed", "3", "--quiet", "--out", str(out)])
    assert code == 0
    page = (out / "report.html").read_text()
    verdicts = page.split('class="verdicts"')[1].split("</table>")[0]
    assert "<td>mc</td><td>yes</td><td>yes</td><td>both</td>" in verdicts
    assert "<td>dim</td><td>no</td><td>no</td><td>neither</td>" in verdicts
    # a missing function, a bad spec and two targets at once are clear errors
    assert main(["converge", "--target", "my_toy_renderer:nope", "--quiet", "--out", str(out)]) == 2
    assert "no function or Target named 'nope'" in capsys.readouterr().err
    assert main(["converge", "--target", "my_toy_renderer:NOT_CALLABLE", "--quiet", "--out", str(out)]) == 2
    assert "no function or Target named 'NOT_CALLABLE'" in capsys.readouterr().err
    assert main(["converge", "--target", "no_such_module:evaluate", "--quiet", "--out", str(out)]) == 2
    assert "cannot import module 'no_such_module'" in capsys.readouterr().err
    assert main(["converge", "--target", "my_toy_renderer", "--quiet", "--out", str(out)]) == 2
    assert "module:function" in capsys.readouterr().err
    assert main(["converge", "cornell", "--target", "my_toy_renderer:evaluate", "--out", str(out)]) == 2
    assert "not both" in capsys.readouterr().err


def test_render_method_flag_its_alias_and_the_registry_in_the_help(tmp_path, capsys):
    """``--method`` names the method (``--integrator`` is an alias; both is an
    error), the help lists every registered method, and an image too big for
    memory is refused before anything is allocated."""
    import numpy as np

    from mcvar.integrators import METHODS

    base = ["render", "cornell", "--res", "4", "--spp", "2", "--quiet", "--uniform"]
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    assert main(base + ["--method", "direct", "--out", str(a)]) == 0
    assert main(base + ["--integrator", "direct", "--out", str(b)]) == 0
    assert np.array_equal(np.load(a), np.load(b))
    assert main(base + ["--method", "direct", "--integrator", "path", "--out", str(a)]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["render", "cornell", "--res", "1000000", "--quiet", "--out", str(a)]) == 2
    assert "max_memory" in capsys.readouterr().err
    help_text = build_parser()._subparsers._group_actions[0].choices["render"].format_help()
    assert all(name in help_text.replace("\n", " ").replace("  ", " ") for name in METHODS)


def test_render_glass_splits_flag(tmp_path, capsys):
    """``--glass-splits N`` reaches the path settings: the adaptive default splits (1), 0
    gives another image of the same seed, and a negative count is refused naming it."""
    import numpy as np

    base = ["render", "cornell-spheres", "--res", "8", "--spp", "16", "--quiet", "--seed", "3", "--workers", "1"]
    a, b, c = tmp_path / "a.npy", tmp_path / "b.npy", tmp_path / "c.npy"
    assert main(base + ["--out", str(a)]) == 0
    assert main(base + ["--glass-splits", "1", "--out", str(b)]) == 0
    assert main(base + ["--glass-splits", "0", "--out", str(c)]) == 0
    assert np.array_equal(np.load(a), np.load(b)) and not np.array_equal(np.load(a), np.load(c))
    assert main(base + ["--glass-splits", "-1", "--out", str(c)]) == 2
    assert "glass_splits" in capsys.readouterr().err


def test_adaptive_workers_follow_the_cpus_this_process_may_use(monkeypatch):
    """``mcvar render``'s default split: two workers when the process may run on two
    CPUs or more (the affinity mask, not the machine's count), one when pinned to one;
    an explicit ``--workers`` is kept."""
    from mcvar import cli

    monkeypatch.setattr(cli.os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert cli._adaptive_workers(None) == 1
    assert cli._adaptive_workers(2) == 2
    monkeypatch.setattr(cli.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert cli._adaptive_workers(None) == 2
    monkeypatch.delattr(cli.os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(cli.os, "cpu_count", lambda: 1)
    assert cli._adaptive_workers(None) == 1
