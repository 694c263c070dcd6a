"""What a new user meets at the command line: help with no arguments, a version, STAGE/PREFIX keys,
options that do not apply refused or said, lines that say whether a task was achieved and whether a
plan's cost rose, help texts made from the code they describe, errors that name the option typed and
the command that makes a missing input, and a start-up that does not load the heavy libraries."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from raico.pipeline.engine.runner import Outcome, outcome_line, outcome_notes

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def arm_plan(raico, tmp_path_factory):
    """A short pseudo-dynamics plan of the 5-joint arm and its artifacts folder."""
    root = tmp_path_factory.mktemp("arts")
    res = raico("plan", "--plant", "arm5", "--task", "reach", "--iterations", "3", "--no-record", "--json",
                 "--artifacts", root)
    assert res.exit_code == 0, res.output
    return root, json.loads(res.stdout.strip().splitlines()[-1])["key"]


def test_no_arguments_prints_the_help(raico):
    res = raico()
    assert res.exit_code == 0 and "raico: error" not in res.output
    assert "Usage: " in res.stdout and "Commands:" in res.stdout and "plan" in res.stdout


def test_version(raico):
    from importlib.metadata import version

    res = raico("--version")
    assert res.exit_code == 0 and res.stdout.strip() == f"raico {version('raico')}"


def test_show_takes_stage_slash_prefix(raico, arm_plan):
    root, key = arm_plan
    res = raico("show", f"plan/{key[:4]}", "--artifacts", root)
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["key"] == key
    bad = raico("show", f"dance/{key[:4]}", "--artifacts", root)
    assert bad.exit_code == 2 and "unknown stage 'dance'" in bad.stderr
    other = raico("show", f"babble/{key[:4]}", "--artifacts", root)
    assert other.exit_code == 2 and f"'{key[:4]}' is a plan artifact, not a babble artifact" in other.stderr


@pytest.mark.parametrize("args,needle", [
    (["--controller", "wbc"], "--controller wbc is for plans of a floating robot; this plan is of arm5"),
    (["--start", "standing"], "--start standing is for plans of a floating robot; this plan is of arm5"),
])
def test_floating_options_refused_for_an_arm_plan(raico, arm_plan, args, needle):
    root, key = arm_plan
    res = raico("execute", "--plan", key, *args, "--no-record", "--artifacts", root)
    assert res.exit_code == 2, res.stderr
    line = res.stderr.strip()
    assert line.startswith(f"raico: error: {needle}") and "\n" not in line, res.stderr
    assert not (root / "execute").exists() or not any((root / "execute").iterdir())


def test_an_option_the_solver_does_not_use_is_said_and_kept_out_of_the_key(raico, tmp_path):
    base = ["plan", "--plant", "arm5", "--task", "reach", "--solver", "aico", "--iterations", "2", "--no-record",
            "--json", "--artifacts", tmp_path]
    plain = raico(*base)
    with_alpha = raico(*base, "--alpha", "10")
    assert plain.exit_code == with_alpha.exit_code == 0
    assert "--alpha 10.0 is ignored: it is R-AICO's (--solver raico), not aico's" in with_alpha.stderr
    assert "ignored" not in plain.stderr
    key = [json.loads(r.stdout.strip().splitlines()[-1])["key"] for r in (plain, with_alpha)]
    assert key[0] == key[1]


def test_plan_config_says_what_it_ignores():
    from raico.stages.plan.stage import PlanConfig

    assert PlanConfig(plant="arm5", task="reach", solver="raico", alpha=10).ignored() == {}
    got = PlanConfig(plant="arm5", task="reach", solver="ilqg", alpha=10, belief_rate=0.5, balance_margin=0.02).ignored()
    assert set(got) == {"alpha", "belief_rate", "balance_margin"}


def test_the_execute_line_says_whether_the_task_was_achieved():
    def execute(status, err):
        return Outcome("execute", "k", "/p", False, status, {"via_point_errors": {"via_x@10": err}})

    assert "task achieved: largest via-point error 0.004 <= 0.01" in outcome_line(execute("ok", 0.004))
    assert "task missed: largest via-point error 0.03 > 0.01" in outcome_line(execute("ok", 0.03))
    assert "task missed" in outcome_line(execute("fell", 0.004))            # stood is part of achieving it
    assert outcome_notes(Outcome("execute", "k", "/p", False, "ok", {})) == []


def test_a_plan_whose_cost_rose_is_said():
    def plan(first, final):
        return Outcome("plan", "k", "/p", False, "max-iterations",
                       {"first_iteration_cost": first, "final_cost": final})

    rose = outcome_notes(plan(10.0, 270.0))
    assert rose == ["warning: the cost rose over the iterations, from 10 after the first to 270 (27x)"]
    assert outcome_notes(plan(10.0, 3.0)) == [] and outcome_notes(plan(10.0, None)) == []


def test_the_learn_line_says_achieved_or_missed():
    out = Outcome("learn", "k", "/p", False, "ok", {"achieved": [False, True, False]})
    assert outcome_notes(out) == ["task missed in the last episode (1/3 episodes achieved it)"]


def test_help_texts_come_from_the_code(raico):
    from raico.planning.solvers import SOLVERS
    from raico.stages.plan.balance import MARGIN
    from raico.stages.registry import DESCRIPTIONS

    plan_help = " ".join(raico("plan", "--help").stdout.split())
    for name in SOLVERS:
        assert name in "".join(plan_help.split())        # help wraps at hyphens
    assert f"kept {MARGIN * 100:g} cm" in plan_help
    learn_help = " ".join(raico("learn", "--help").stdout.split())
    assert " ".join(DESCRIPTIONS["learn"].split()) in learn_help and "R-AICO with --alpha > 0" in learn_help
    execute_help = raico("execute", "--help").stdout
    assert re.search(r"--plan <str>\s+Key \(or prefix\) of a plan artifact\.\s+\[required\]", execute_help)
    for name, text in DESCRIPTIONS.items():
        assert "".join(text.split()) in "".join(raico(name, "--help").stdout.split())


def test_errors_name_the_option_typed(raico):
    res = raico("plan", "--plant", "arm5", "--task", "reach", "--alpha-schedule", "sometimes")
    assert res.exit_code == 2 and ("raico: error: --alpha-schedule must be one of fixed, adaptive, robust, got "
                                   "'sometimes'") in res.stderr


def test_errors_say_which_command_makes_the_missing_input(raico, arm_plan, tmp_path):
    root, key = arm_plan
    ex = raico("execute", "--plan", key, "--no-record", "--json", "--artifacts", root)
    assert ex.exit_code == 0, ex.output
    ekey = json.loads(ex.stdout.strip().splitlines()[-1])["key"]
    res = raico("execute", "--plan", ekey, "--artifacts", root)
    assert res.exit_code == 2
    assert f"'{ekey}' is an execute artifact, not a plan artifact; `raico plan` makes a plan artifact" in res.stderr
    res = raico("plan", "--plant", "arm5", "--task", "reach", "--dynamics", "learned", "--model", key,
                 "--artifacts", root)
    assert res.exit_code == 2 and "is a plan artifact, not a fit artifact; `raico fit --data BABBLE_KEY`" in res.stderr
    res = raico("plan", "--plant", "arm5", "--task", "reach", "--dynamics", "learned", "--model", "abcdef",
                 "--artifacts", tmp_path)
    assert res.exit_code == 3 and "`raico fit --data BABBLE_KEY` makes a fit artifact" in res.stderr


_PROBE = """
import runpy, sys
sys.argv = ["raico", *sys.argv[1:]]
try:
    runpy.run_module("raico.pipeline.interface.cli", run_name="__main__")
except SystemExit:
    pass
print("HEAVY", sorted(m for m in ("pydrake", "crocoddyl", "ray", "scipy", "rerun", "raico.stages.plan.stage")
                      if m in sys.modules))
"""


@pytest.mark.parametrize("args", [["--help"], ["--version"], [], ["nope"]])
def test_help_and_usage_errors_load_no_heavy_library(args):
    out = subprocess.run([sys.executable, "-c", _PROBE, *args], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert "HEAVY []" in out.stdout, out.stdout[-500:] + out.stderr[-500:]


@pytest.mark.parametrize("args", [["plan", "--plant", "arm5", "--task", "reach", "--solver", "foo"],
                                  ["execute", "--plan", "abc", "--controller", "foo"],
                                  ["babble", "--plant", "crane"], ["learn", "--plant", "crane", "--task", "x"]])
def test_a_refused_option_loads_neither_drake_nor_crocoddyl_nor_ray(args):
    out = subprocess.run([sys.executable, "-c", _PROBE, *args], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert "raico: error:" in out.stderr
    heavy = re.search(r"HEAVY \[(.*)\]", out.stdout).group(1)
    assert not {"'pydrake'", "'crocoddyl'", "'ray'"} & set(heavy.split(", ")), heavy


def test_a_signal_inside_an_import_is_the_interrupt():
    """A SIGTERM that lands while an extension module initializes surfaces as its ImportError; the CLI
    reports the interrupt (exit 143), not the import (tests/pipeline/test_faults.py kills a babble run mid-stage)."""
    from raico.pipeline.lifecycle import Interrupted, interrupt_in

    try:
        try:
            raise Interrupted(15)
        except Interrupted:
            raise ImportError("initialization failed") from None
    except ImportError as e:
        assert interrupt_in(e) is None                   # `from None`: no interrupt behind it
    try:
        try:
            raise Interrupted(15)
        except Interrupted:
            raise ImportError("initialization failed")  # noqa: B904 - as an extension module's init does
    except ImportError as e:
        assert interrupt_in(e).signum == 15
    assert interrupt_in(ValueError("x")) is None


def test_the_quick_report_is_labelled_a_smoke_test():
    from raico.thesis.report import SMOKE, markdown_claims

    rows = [{"figure": "fig3.2a", "claim": "c", "thesis": '§3.5: "x" (Fig. 3.2A)', "criterion": "k", "measured": "m",
             "verdict": "does not hold", "why": "because"}]
    real, smoke = markdown_claims(rows), markdown_claims(rows, smoke=True)
    assert "**does not hold** (why: because)" in real and SMOKE not in real
    assert f"does not hold ({SMOKE})" in smoke and "**" not in smoke.split("\n")[-1]


def test_the_call_line_counts_jobs_in_english():
    from raico.thesis.reproduce import call_line

    call = {"figures": 1, "runs": 10, "cached_runs": 0, "jobs": 1, "wall_time_s": 3.0, "cpu_time_s": 2.0,
            "main_cpu_time_s": 1.0, "when": "now", "load_average_1min": 0.5}
    assert "1 figure, 10 runs (0 cached) with 1 job:" in call_line(call)
    assert "with 2 jobs:" in call_line({**call, "jobs": 2})


def test_a_whole_stage_slash_key_is_found_without_listing_the_stage(tmp_path, monkeypatch):
    """The pipeline names inputs as STAGE/KEY: resolving one must not check every entry of the stage
    (a reproduce resolves hundreds; listing made a cached reproduce 25 times slower)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import find_entry
    from raico.pipeline.errors import MissingArtifact

    cache = Cache(tmp_path)
    monkeypatch.setattr(Cache, "list", lambda *a, **k: pytest.fail("listed the stage"))
    with pytest.raises(MissingArtifact):
        find_entry(cache, "plan/0123456789abcdef", stage="plan")
