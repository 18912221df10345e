"""Property tests (Hypothesis) of what a user can throw at bioslam: random configurations,
random TUM files and random command lines on tiny logs. Whatever the input, no traceback: a
clear error (naming the file, and the key or line) or a result that holds together.

Derandomized so that CI runs the same corpus every time; the example counts keep the module
within a few tens of seconds.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import tempfile
import typing
from pathlib import Path
from unittest import mock

from _cli_logs import write_carmen
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from bioslam.cli import main
from bioslam.config import SLAMConfig, config_from_dict
from bioslam.io.outdir import MARKER
from bioslam.io.tum import read_tum

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def strict_json(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


# --- configurations -------------------------------------------------------------------------


def _leaves(cls: type, prefix: str = "") -> list[tuple[str, typing.Any]]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint):
            out += _leaves(hint, f"{prefix}{f.name}.")
        else:
            out.append((prefix + f.name, hint))
    return out


LEAVES = _leaves(SLAMConfig)
SECTIONS = sorted({key.rsplit(".", 1)[0] for key, _ in LEAVES if "." in key})
ANY_VALUE = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**12),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
    st.lists(st.one_of(st.integers(-5, 50), st.floats(-1, 50)), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def _nested(pairs: list[tuple[str, typing.Any]]) -> dict:
    root: dict = {}
    for key, value in pairs:
        node = root
        *parents, leaf = key.split(".")
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                break
            node = child
        else:
            node[leaf] = value
    return root


@st.composite
def configs(draw) -> dict:
    """A few settings, each a wrong type, an extreme, a plausible value or an unknown key;
    sometimes a section replaced by a scalar."""
    pairs = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["known", "known", "unknown", "section"]))
        if kind == "unknown":
            pairs.append((draw(st.sampled_from([*SECTIONS, ""])) + ".zz_" + draw(
                st.text("abc", min_size=1, max_size=3)), draw(ANY_VALUE)))
        elif kind == "section":
            pairs.append((draw(st.sampled_from(SECTIONS)), draw(ANY_VALUE)))
        else:
            key, _ = draw(st.sampled_from(LEAVES))
            default = _default(key)
            plausible = (st.floats(0.5, 2.0).map(lambda f, d=default: type(d)(d * f))
                         if isinstance(default, (int, float)) and not isinstance(default, bool)
                         else ANY_VALUE)
            pairs.append((key, draw(st.one_of(plausible, plausible, plausible, ANY_VALUE))))
    return _nested([(k.lstrip("."), v) for k, v in pairs])


def _default(key: str):
    obj = SLAMConfig()
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def _typed(config: SLAMConfig) -> None:
    """Every accepted value has its field's type and is finite."""
    for key, hint in LEAVES:
        value = _default_of(config, key)
        if hint is float:
            assert type(value) is float and math.isfinite(value), key
        elif hint in (int, bool):
            assert type(value) is hint, key


def _default_of(config: SLAMConfig, key: str):
    obj = config
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


@settings(FUZZ, max_examples=150)
@given(configs())
def test_random_configs_are_accepted_typed_or_refused_by_name(overrides):
    try:
        config = config_from_dict(overrides, "fuzz.toml")
    except ValueError as exc:
        assert str(exc).startswith("fuzz.toml: "), exc
        event("refused")
        return
    event("accepted")
    _typed(config)


# --- TUM files and eval ---------------------------------------------------------------------

TUM_LINE = st.one_of(
    st.just("VALID"), st.just("VALID"), st.just("VALID"), st.just("# comment"), st.just(""),
    st.just("REPEAT"), st.text(max_size=30),
    st.lists(st.sampled_from(["0", "1.5", "nan", "inf", "-1e308", "x", "1e400"]),
             min_size=7, max_size=9).map(" ".join),
)


@st.composite
def tum_texts(draw) -> str:
    lines, t = [], 0.0
    for kind in draw(st.lists(TUM_LINE, max_size=40)):
        if kind == "VALID":
            t += draw(st.floats(0.001, 0.5))
            x, y = draw(st.floats(-50, 50)), draw(st.floats(-50, 50))
            lines.append(f"{t:.6f} {x} {y} 0 0 0 {draw(st.floats(-1, 1))} 1")
        elif kind == "REPEAT":
            lines.append(f"{t:.6f} 0 0 0 0 0 0 1")
        else:
            lines.append(kind)
    return "\n".join(lines) + "\n"


@settings(FUZZ, max_examples=150)
@given(tum_texts())
def test_random_tum_files_read_whole_or_name_the_line(text):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.tum"
        path.write_text(text, encoding="latin-1", errors="replace")
        try:
            trajectory = read_tum(path)
        except ValueError as exc:
            head, line = str(exc).split(":", 2)[:2]
            assert head == str(path) and 1 <= int(line) <= text.count("\n"), exc
            event("refused")
            return
        event("read")
        assert all(math.isfinite(v) for v in trajectory.poses.ravel())
        assert all(b > a for a, b in zip(trajectory.stamps, trajectory.stamps[1:], strict=False))


@st.composite
def clean_tum_texts(draw) -> str:
    """Well-formed trajectories on a shared 0.1 s grid (so that two of them associate)."""
    n = draw(st.integers(0, 40))
    xy = draw(st.lists(st.floats(-0.05, 0.05), min_size=2 * n, max_size=2 * n))
    return "".join(f"{0.1 * k:.6f} {0.1 * k + xy[2 * k]} {xy[2 * k + 1]} 0 0 0 0 1\n"
                   for k in range(n))


def _cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse refusing the arguments
            code = exc.code
    return code, out.getvalue(), err.getvalue()


@settings(FUZZ, max_examples=60)
@given(st.one_of(clean_tum_texts(), tum_texts()), st.one_of(clean_tum_texts(), tum_texts()),
       st.sampled_from(["0.02", "0.02", "0.5", "0", "-1", "nan", "x"]),
       st.sampled_from([None, None, "1", "3", "0"]))
def test_eval_on_random_files_gives_strict_json_or_a_clear_error(est, ref, max_dt, pairs):
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "a.tum", Path(tmp) / "b.tum"
        a.write_text(est)
        b.write_text(ref)
        argv = ["eval", str(a), str(b), "--max-dt", max_dt]
        argv += ["--min-pairs", pairs] if pairs else []
        code, out, err = _cli(argv)
    event(f"eval exit {code}")
    assert code in (0, 2), err
    assert "Traceback" not in err
    if code == 0:
        summary = strict_json(out.strip().splitlines()[-1])
        assert summary["pairs"] >= int(pairs or 10)
    else:
        assert "error" in err


# --- command lines on tiny logs -------------------------------------------------------------


class Files:
    """Inputs of the command-line fuzz, made once per example in a fresh directory."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.good = write_carmen(root / "good.log", scans=15)
        self.partial = write_carmen(root / "partial.log", scans=15, bad={1, 4, 7, 10})
        self.junk = root / "junk.log"
        self.junk.write_bytes(bytes(range(256)) * 4)
        (root / "ok.toml").write_text("[odometry]\nresolution = 0.06\n")
        (root / "bad.toml").write_text("[odometry]\nresolution = true\n")
        (root / "list.json").write_text("[1, 2]")
        (root / "gt.tum").write_text(
            "".join(f"{100 + 0.1 * k:.6f} {0.05 * k} 0 0 0 0 0 1\n" for k in range(15)))
        (root / "short.tum").write_text("100 0 0 0 0 0 0 1\n")
        (root / "a_file").write_text("x")
        used = root / "used"
        used.mkdir()
        (used / MARKER).write_text(json.dumps({"files": ["trajectory.tum", "../good.log"]}))
        (used / "trajectory.tum").write_text("stale\n")

    def path(self, name: str) -> str:
        return str(self.root / name)


OPTIONS = {  # each option's good values repeated: most lines should get to run
    "--config": ["ok.toml", "ok.toml", "bad.toml", "list.json", "missing.toml"],
    "--gt": ["gt.tum", "gt.tum", "short.tum", "junk.log", "missing.tum"],
    "--min-read-share": ["0", "0.5", "0.9", "0.9", "1", "2", "x"],
    "--topic": ["FLASER", "FLASER", "/scan"],
}
FLAGS = ["--overwrite", "--accept-partial", "--odometry-only", "--no-progress"]


@st.composite
def command_lines(draw) -> tuple[str, list[tuple[str, str | None]]]:
    command = draw(st.sampled_from(["run", "run", "run", "info"]))
    log = draw(st.sampled_from(["good.log"] * 4 + ["partial.log"] * 3 + ["junk.log", "used",
                                                                         "missing.log"]))
    options: list[tuple[str, str | None]] = [("INPUT", log)]
    if command == "run":
        options.append(("--out", draw(st.sampled_from(["out"] * 4 + ["used", "a_file",
                                                                    "deep/er/out"]))))
        for name, values in OPTIONS.items():
            if draw(st.integers(0, 4)) == 0:
                options.append((name, draw(st.sampled_from(values))))
        options += [(flag, None) for flag in FLAGS if draw(st.booleans())]
    else:
        options += [(flag, None) for flag in ("--accept-partial", "--strict")
                    if draw(st.booleans())]
    return command, options


@settings(FUZZ, max_examples=24)
@given(command_lines())
def test_random_command_lines_never_trace_back(line):
    command, options = line
    with tempfile.TemporaryDirectory() as tmp, mock.patch("bioslam.pipeline.warm_up",
                                                          lambda *a, **k: 0.0):
        files = Files(Path(tmp))
        argv = [command]
        for name, value in options:
            if name == "INPUT":
                argv.append(files.path(value))
            elif value is None:
                argv.append(name)
            else:
                path_like = name in ("--out", "--config", "--gt")
                argv += [name, files.path(value) if path_like else value]
        code, out, err = _cli(argv)
        event(f"{command} exit {code}")
        assert "Traceback" not in err
        assert code in (0, 1, 2), (argv, code, err)
        if code == 2:
            assert "error" in err, (argv, err)
        else:
            summary = strict_json(out.strip().splitlines()[-1])
            if code == 0:
                assert summary["scans"] > 0
            _check_output_dir(argv, summary)
        assert (files.root / "good.log").is_file()  # a marker's '..' entry is never followed


def _check_output_dir(argv: list[str], summary: dict) -> None:
    if "--out" not in argv:
        return
    out = Path(argv[argv.index("--out") + 1])
    marker = json.loads((out / MARKER).read_text())
    assert marker["status"] in ("complete", "incomplete")
    for name in marker["files"]:
        assert (out / name).is_file(), name
    assert strict_json((out / "summary.json").read_text()) == summary
