"""The report's figures as data: what the cost panels draw equals the tables' medians, diverged runs
are drawn to their last iterate, one colour per solver in every figure, the wall-time panel where
the data asks for it, and the remark on figures that give the same results."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

import raico.pipeline.engine.artifacts
from raico.thesis.figures import EXPERIMENTS, Experiment, Variant, summarize
from raico.thesis.report import (
    FALLBACK_COLORS,
    SOLVER_COLORS,
    cost_at_times,
    cost_panel_data,
    diverged_path,
    figure_colors,
    identical_results_remarks,
    median_band,
    solver_color,
    wall_panel_data,
    wants_wall_panel,
    write_figure,
)


class FakeCache:
    """``cache.require`` hands the key through; ``as_artifact`` (patched) serves the run's arrays."""

    def require(self, stage, key):
        return key


@pytest.fixture
def runs(monkeypatch):
    """Register synthetic plan runs: ``add(variant, seed, costs, status, elapsed=None)`` -> plan dict."""
    arrays: dict[str, dict] = {}

    class Art:
        def __init__(self, key):
            self.key = key

        def arrays(self, name, keys=None):
            d = arrays[self.key]
            return {k: v for k, v in d.items() if keys is None or k in keys}

    monkeypatch.setattr(raico.pipeline.engine.artifacts, "as_artifact", lambda entry: Art(entry))

    def add(variant, seed, costs, status="max-iterations", elapsed=None, initial=1e4):
        key = f"{variant.label}/{seed}"
        costs = np.asarray(costs, float)
        elapsed = np.cumsum(np.full(costs.size, 0.01)) if elapsed is None else np.asarray(elapsed, float)
        arrays[key] = {"costs": costs, "elapsed": elapsed}
        metrics = {"final_cost": float(costs[-1]) if costs.size else initial, "initial_cost": initial,
                   "first_iteration_cost": float(costs[0]), "cost_ratio": float(costs[-1]) / initial,
                   "iterations": int(costs.size), "wall_time_s": float(elapsed[-1])}
        return {"variant": variant, "seed": seed,
                "outcome": SimpleNamespace(key=key, status=status, metrics=metrics)}

    return add


ILQG, AICO, R1 = Variant("ilqg"), Variant("aico"), Variant("raico", 1.0)
EXP = Experiment("figT", "arm5", "reach", "pseudo", (ILQG, AICO, R1), 6, 2, "synthetic")


def synthetic_plans(add):
    """iLQG: runs that stopped early (converged) and one that diverged in iteration 4; AICO: all
    diverged in iteration 1; R-AICO: an even number of runs over the full budget."""
    rng = np.random.default_rng(0)
    plans = []
    for s in range(5):
        n = 6 - s % 3  # 6, 5, 4 iterations: the shorter ones converged
        c = np.sort(rng.uniform(10, 1000, n))[::-1]
        plans.append(add(ILQG, s, c, "converged" if n < 6 else "max-iterations"))
    plans.append(add(ILQG, 5, [500.0, 300.0, 200.0, math.inf], "diverged"))
    plans += [add(AICO, s, [math.inf], "diverged", initial=2e4 + s) for s in range(3)]
    plans += [add(R1, s, np.geomspace(1000 + 100 * s, 50 + 7 * s, 6), elapsed=np.arange(1, 7) * 0.05)
              for s in range(4)]  # five times iLQG's time per iteration
    return plans


def test_median_line_ends_at_the_tables_median_final_cost(runs):
    plans = synthetic_plans(runs)
    rows = {r["label"]: r for r in cost_panel_data(FakeCache(), EXP, plans)}
    for v in (ILQG, R1):
        r, table = rows[v.label], summarize(plans, v)
        assert r["median"][-1] == table["final_cost_median"]  # the same statistic, exactly
        assert r["runs"] == table["runs"]
    # R-AICO: four finite runs, the median averages the middle two; the band is the 25-75 % range
    finals = np.array([np.geomspace(1000 + 100 * s, 50 + 7 * s, 6)[-1] for s in range(4)])
    r = rows[R1.label]
    assert r["median"][-1] == pytest.approx(np.mean(np.sort(finals)[1:3]))
    assert (r["q25"][-1], r["q75"][-1]) == pytest.approx(tuple(np.percentile(finals, [25, 75])))
    assert np.all(r["q25"] <= r["median"]) and np.all(r["median"] <= r["q75"])
    # the band is of the costs, not of their logarithm: every value lies within the runs' range
    C = np.array([np.geomspace(1000 + 100 * s, 50 + 7 * s, 6) for s in range(4)])
    assert np.all(r["q25"] >= C.min(0)) and np.all(r["q75"] <= C.max(0))
    # AICO diverged everywhere: no median, its runs drawn to the initial guess (iteration 0)
    a = rows[AICO.label]
    assert np.all(np.isnan(a["median"])) and len(a["diverged"]) == 3
    assert [(list(x), list(y)) for x, y in a["diverged"]] == [([0], [2e4 + s]) for s in range(3)]


def test_median_band_on_columns_with_missing_runs():
    C = np.array([[4.0, 2.0, np.nan], [6.0, np.inf, np.nan], [8.0, 3.0, np.nan]])
    m, lo, hi = median_band(C)
    assert list(m[:2]) == [6.0, 2.5] and np.isnan(m[2]) and np.isnan(lo[2]) and np.isnan(hi[2])
    assert (lo[0], hi[0]) == (5.0, 7.0)


def test_diverged_run_is_drawn_to_its_last_iterate_before_the_divergence(runs):
    assert [list(a) for a in diverged_path([500.0, 300.0, 200.0, math.inf], 1e4, 4)] == [[0, 1, 2, 3],
                                                                                      [1e4, 500, 300, 200]]
    # a divergence by size (finite, far above the start) is not drawn either
    assert [list(a) for a in diverged_path([500.0, 1e12], 1e4, 2)] == [[0, 1], [1e4, 500]]
    assert [list(a) for a in diverged_path([math.inf], 2e4, 1)] == [[0], [2e4]]
    plans = synthetic_plans(runs)
    r = next(r for r in cost_panel_data(FakeCache(), EXP, plans) if r["label"] == "iLQG")
    assert len(r["diverged"]) == 1 and list(r["diverged"][0][1]) == [1e4, 500, 300, 200]


def test_wall_time_band_ends_at_the_tables_median(runs):
    plans = synthetic_plans(runs)
    rows = {r["label"]: r for r in wall_panel_data(FakeCache(), EXP, plans, points=50)}
    for v in (ILQG, R1):
        assert rows[v.label]["median"][-1] == summarize(plans, v)["final_cost_median"]
    assert np.all(np.isnan(rows["AICO"]["median"]))
    # the diverged iLQG run: its iterations before the divergence, against their end times
    t, y = rows["iLQG"]["diverged"][0]
    assert list(y) == [500, 300, 200] and list(t) == pytest.approx([0.01, 0.02, 0.03])
    at = cost_at_times(np.array([[5.0, 3.0]]), np.array([[1.0, 2.0]]), np.array([0.5, 1.0, 1.5, 2.5]))
    assert np.isnan(at[0, 0]) and list(at[0, 1:]) == [5.0, 5.0, 3.0]


def test_wall_time_panel_where_the_data_asks_for_it():
    fddp = Experiment("f", "arm5", "reach", "analytic", (R1, Variant("fddp")), 6, 2, "")
    assert wants_wall_panel(fddp, {})  # the crocoddyl baseline: always
    assert wants_wall_panel(EXP, {"iLQG": 0.2, "R-AICO a=1": 0.025})
    assert not wants_wall_panel(EXP, {"iLQG": 0.03, "AICO": 0.029, "R-AICO a=1": 0.02})
    assert not wants_wall_panel(EXP, {"iLQG": 0.03})


def test_one_colour_per_solver_across_all_figures():
    seen: dict[str, str] = {}
    for exp in EXPERIMENTS.values():
        labels = [v.label for v in exp.variants]
        colors = figure_colors(labels)
        assert len(set(colors.values())) == len(labels), exp.id  # distinct within the figure
        for lab, c in colors.items():
            assert seen.setdefault(lab, c) == c, lab  # the same in every figure
            assert c == solver_color(lab)
    # the thesis's solvers, the ablation, the adaptive schedule and the crocoddyl baseline are named
    for lab in ("iLQG", "AICO", "AICO (no sweep relinearization)", "R-AICO a=1", "R-AICO a=10"):
        assert lab in SOLVER_COLORS
    assert solver_color("R-AICO adaptive (a0=1)") == solver_color("R-AICO adaptive (a0=10)") == "tab:cyan"
    assert solver_color("R-AICO adaptive (a0=1)") not in SOLVER_COLORS.values()


def test_unknown_labels_get_a_deterministic_distinct_colour():
    c = solver_color("some new solver")
    assert c in FALLBACK_COLORS and c == solver_color("some new solver")
    # two labels that would share a colour (a prefix) are told apart within a figure, deterministically
    labels = ["iLQG", "R-AICO adaptive (a0=1)", "R-AICO adaptive (a0=10)", "some new solver"]
    colors = figure_colors(labels)
    assert len(set(colors.values())) == 4 and colors == figure_colors(list(reversed(labels)))
    assert colors["iLQG"] == SOLVER_COLORS["iLQG"]


def row(label, final, via=0.05, terms=None, first=1000.0, wall=1.0):
    return {"label": label, "runs": 10, "diverged": 0, "converged": 0, "final_cost_median": final,
            "first_cost_median": first, "cost_ratio_median": final / first, "cost_ratio_max": final / first,
            "final_cost_max": 1.02 * final, "max_via_error_median": via, "wall_time_median_s": wall,
            "term_medians": terms or {}}


def test_identical_results_are_remarked_with_the_measured_terms(monkeypatch):

    c = {"figure": "fig3.2c", "summary": [row("iLQG", 2400.0), row("R-AICO a=1", 473.5, terms={"control": 445.5})]}
    d = {"figure": "fig3.2d", "summary": [row("iLQG", 3880.0),
                                          row("R-AICO a=1", 473.6, first=1090.0, wall=0.7,
                                              terms={"control": 445.6, "roll": 2.2e-6})]}
    remarks = identical_results_remarks([c, d])
    assert list(remarks) == ["fig3.2d"] and len(remarks["fig3.2d"]) == 1
    text = remarks["fig3.2d"][0]
    assert "fig3.2c and fig3.2d give the same results for R-AICO a=1**" in text and "iLQG" not in text.split("**")[1]
    assert "roll (fig3.2d only)" in text and "roll costs 2.2e-06 (R-AICO a=1)" in text
    assert "control 445.5 -> 445.6 (R-AICO a=1, +0.1)" in text and text.endswith("Why: not examined.")
    # to the tables' precision only: a stricter tolerance, or results that differ, give no remark
    assert identical_results_remarks([c, d], rtol=1e-9) == {}
    d["summary"][1]["max_via_error_median"] = 0.06
    assert identical_results_remarks([c, d]) == {}
    # learning figures (other summaries) and figures without a summary are not compared
    assert identical_results_remarks([{"figure": "fig4.3", "summary": [{"label": "every"}]},
                                      {"figure": "fig4.1/4.2", "summary": [{"label": "every"}]}]) == {}


def test_figure_renders_from_the_panels_data(runs, tmp_path):
    import matplotlib.image as mpimg

    plans = synthetic_plans(runs)
    write_figure(FakeCache(), EXP, plans, tmp_path / "figure.png")
    img = mpimg.imread(tmp_path / "figure.png")
    assert img.shape[1] > 1000 and img[..., :3].std() > 0.05  # two panels (time per iteration differs), not blank


def test_missed_rows_keep_the_stabilizer_runs_that_did_not_achieve():
    """The stabilizer's runs that missed (status ok but a via-point beyond 1 cm, or another status) and the noisy
    ones that fell, with the reference's joints past their range and the margins; achieved, joint-PD and noisy runs
    that stood left out."""
    from types import SimpleNamespace

    from raico.thesis.report import missed_rows, missed_section

    def run(key, status, errs, ctrl="wbc", margins=None, beyond=None, ref=0.03):
        return SimpleNamespace(key=key, metrics={"status": status, "reason": status, "controller": ctrl,
                                                 "via_point_errors": {"r_sole@max": 0.5, **errs},
                                                 "cog_via_point_margins": margins or {},
                                                 "reference_cog_min_margin": ref, "reference_cog_min_margin_time": 2.2,
                                                 "reference_beyond_limits": beyond or {}})

    runs = [run("achieved", "ok", {"via_cog2@200": 0.009}),
            run("short", "ok", {"via_cog1@100": 0.001, "via_cog2@200": 0.017}, margins={"via_cog2@200": 0.005},
                beyond={"RAnkleRoll": 0.04}),
            run("fell", "fell", {"via_cog2@200": 0.002}),
            run("pd", "fell", {"via_cog2@200": 0.3}, ctrl="pd")]
    fell_noisy = run("noisy-fell", "fell", {"via_cog2@200": 0.1}, ref=0.001)
    fell_noisy.metrics.update(failure_time=1.5, reference_cog_margin_at_failure=0.012)
    noisy = [{"outcome": fell_noisy, "level": (0.02, 0.5)},
             {"outcome": run("noisy-stood", "limits", {"via_cog2@200": 0.1}), "level": (0.02, 0.5)},
             {"outcome": run("quiet", "fell", {"via_cog2@200": 0.1}), "level": (0.0, 0.0)}]
    rows = missed_rows(runs, noisy)
    assert [r["key"] for r in rows] == ["short", "fell", "noisy-fell"]
    assert rows[0]["via_point"] == "via_cog2@200" and rows[0]["error"] == 0.017 and rows[0]["target_margin"] == 0.005
    assert rows[0]["beyond_limits"] == {"RAnkleRoll": 0.04} and rows[2]["noise"] == "x0 0.02 rad, 0.5 N m"
    md, _ = missed_section(runs, noisy)
    assert "2 of 3 stabilizer runs without noise did not achieve" in md[2] and "; 1 run under noise fell" in md[2]
    assert "comes to 0.001 to 0.03 m of the edge in the runs below, to 0.03 to 0.03 m in the 1 that achieved" in md[2]
    assert "past its range in 1 of the 3 runs below and in 0 of the 1 that achieved" in md[2]
    assert "RAnkleRoll 0.040" in md[-4] and md[-3].endswith("| none |") and "| 0.001, 2.2 (at the failure, 1.5 s: 0.012) |" in md[-2]
    assert missed_section(runs[:1]) == ([], [])


def test_noise_section_counts_statuses_and_the_motors_clamping_the_noise(tmp_path):
    """The noise table on synthetic runs: success rate, stood, and the median share of samples in which a
    motor clamped the noise (reported beside the statuses, which judge the controller's own command)."""
    from raico.thesis.report import noise_section

    def run(status, clamped, seed):
        m = {"status": status, "via_point_errors": {"v": 0.01 * (seed + 1)}, "effort_clamped_fraction": clamped}
        return {"controller": "wbc", "level": (0.02, 0.5), "plan_seed": seed, "seed": seed,
                "outcome": SimpleNamespace(key=f"k{seed}", status=status, metrics=m)}

    noise = [run("ok", 0.2, 0), run("limits", 0.6, 1), run("fell", 0.5, 2)]
    md, rows = noise_section(EXPERIMENTS["fig3.4-support"], noise, tmp_path)
    (row,) = rows
    assert (row["runs"], row["ok"], row["stood"], row["clamped_median"]) == (3, 1, 2, 0.5)
    assert any(line.startswith("| stabilizer | 0.02 | 0.5 | 3 | 33 % | 2 |") and line.endswith("| 50 % |")
               for line in md), md
    assert (tmp_path / "noise.png").stat().st_size > 0


def test_cost_panels_draw_mean_and_standard_deviation_and_split_the_thesis_solvers(runs):
    """The thesis draws mean and standard deviation over the initial states: the panel data carries both (median
    beside); the thesis's solvers at the figure's budget go in one panel, long-budget and other variants in another."""
    from raico.thesis.figures import REFERENCE
    from raico.thesis.report import figure_panels, mean_std

    m, sd = mean_std(np.array([[1.0, 4.0], [3.0, np.inf], [5.0, 8.0]]))
    assert list(m) == [3.0, 6.0] and sd[0] == pytest.approx(np.std([1.0, 3.0, 5.0])) and sd[1] == 2.0
    exp = Experiment("figT", "arm5", "reach", "pseudo", (ILQG, AICO, R1, REFERENCE), 6, 2, "synthetic")
    plans = synthetic_plans(runs) + [runs(REFERENCE, s, np.geomspace(900, 40, 12)) for s in range(3)]
    rows = {r["label"]: r for r in cost_panel_data(FakeCache(), exp, plans)}
    assert [lab for lab, r in rows.items() if r["thesis"]] == ["iLQG", "AICO", "R-AICO a=1"]
    assert not rows[REFERENCE.label]["thesis"]
    C = np.array([np.geomspace(1000 + 100 * s, 50 + 7 * s, 6) for s in range(4)])
    assert rows["R-AICO a=1"]["mean"] == pytest.approx(C.mean(0)) and rows["R-AICO a=1"]["std"] == pytest.approx(C.std(0))
    assert figure_panels(exp, list(rows.values()), False, False) == ["cost", "beyond"]
    assert figure_panels(EXP, [r for r in rows.values() if r["thesis"]], True, False) == ["cost", "wall"]
    nao = Experiment("f", "nao", "balance", "pseudo", (R1,), 6, 2, "")
    assert figure_panels(nao, [rows["R-AICO a=1"]], False, True) == ["cost", "cog_plan", "cog", "executed"]


def test_heldout_sentence_says_what_the_curve_does():
    from raico.thesis.report import heldout_sentence, learn_findings

    flat = {"gp_error_heldout_curve": [8.1, 7.9, 8.0, 8.2, 7.7, 8.3, 8.0, 7.9], "gp_error_first3": 600.0,
            "gp_error_last3": 0.008}
    text = heldout_sentence("every", flat)
    assert "stays near its level and does not fall towards zero" in text and "8 rad/s^2 over the first three" in text
    assert "lowest 7.7, highest 8.3" in text
    falling = dict(flat, gp_error_heldout_curve=[8.0, 8.0, 8.0, 4.0, 2.0, 1.0, 1.0, 1.0])
    assert "held-out babbling data falls" in heldout_sentence("every", falling)
    assert heldout_sentence("every", {"gp_error_heldout_curve": [1.0, 2.0]}) is None
    lines = learn_findings({"every": {**flat, "fit_time_s_total": 26.4}, "batch-100": {"fit_time_s_total": 8.8}})
    assert lines[-1].endswith("'every' takes 3x as long.")


def test_claims_table_names_section_figure_runs_setup_and_why():
    from raico.thesis.claims import evaluate_claims
    from raico.thesis.report import markdown_claims
    from tests.thesis.test_evaluate import table

    rows = evaluate_claims(("ilqg_stalls", "raico_converges"), table(ilqg=150, r1=100, r10=120, aico=100), [],
                           "fig3.2c")
    md = markdown_claims(rows)
    thesis, beyond = md.split("### Beyond the thesis")
    assert "### The thesis's claims (0 of 1 hold)" in thesis and "(about Fig. 3.2C,D)" in thesis
    assert "| 10 | arm5 is raico's own light-weight arm" in thesis and "**does not hold** (" in thesis
    assert "(1 of 1 hold)" in beyond and "within the figure's budget (25 iterations)" in beyond


def test_cost_and_wall_panels_leave_out_exploding_iterates_and_say_so(runs):
    """A variant whose early iterates explode (as FDDP's infeasible ones, x0 held: 1e35): the cost and wall-time
    panels span the other values, as ``raico plot`` does, and their titles say what was left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.thesis.report import cost_panel, wall_time_panel

    fddp = Variant("fddp")
    exp = Experiment("figT", "arm5", "reach", "analytic", (R1, fddp), 6, 2, "synthetic")
    plans = [runs(R1, s, np.geomspace(1000 + 100 * s, 50 + 7 * s, 6)) for s in range(3)]
    plans += [runs(fddp, s, [1e35, 3e4, 2e4, 1e4, 9e3, 8e3]) for s in range(3)]
    fig, (ax, ax2) = plt.subplots(1, 2)
    cost_panel(ax, exp, cost_panel_data(FakeCache(), exp, plans), "synthetic", stat="median")
    lo, hi = ax.get_ylim()
    assert hi < 1e6 and lo < 50
    assert "drawn points above" in ax.get_title() and "up to 1e+35; exploding" in ax.get_title()
    wall_time_panel(ax2, wall_panel_data(FakeCache(), exp, plans), {})
    assert ax2.get_ylim()[1] < 1e6 and "up to 1e+35; exploding" in ax2.get_title()
    plt.close(fig)


def test_the_cost_panel_title_names_the_budget_the_runs_had(runs, monkeypatch, tmp_path):
    """--quick runs a figure at its profile's budget: the title says that budget, not the full figure's."""
    import raico.thesis.report as report

    exp = Experiment("figT", "arm5", "reach", "pseudo", (ILQG, R1), 6, 2, "synthetic")   # 6 iterations in full
    plans = [{**runs(v, s, np.geomspace(1000, 50, 3)), "iterations": 3} for v in (ILQG, R1) for s in range(2)]
    shown = {}
    monkeypatch.setattr(report, "save_figure", lambda fig, path, dpi: shown.update(fig=fig))
    write_figure(FakeCache(), exp, plans, tmp_path / "figure.png")
    title = shown["fig"].axes[0].get_title()
    assert "at the figure's budget (3 iterations)" in title and shown["fig"].axes[0].get_xlim()[1] < 4


def test_a_nudged_start_lists_the_chaotic_runs():
    """A variant run again with its start moved by 1e-9 rad: the seeds whose final cost moved by more than 0.1 % are
    chaotic, listed in the report's processor section."""
    from types import SimpleNamespace

    from raico.thesis.figures import Variant
    from raico.thesis.report import nudge_effect, processor_section

    a, b = Variant("aico"), Variant("aico", nudge=1e-9)
    assert b.label == "AICO, start +1e-09 rad"

    def plan(v, seed, cost, via):
        return {"variant": v, "seed": seed, "outcome": SimpleNamespace(metrics={
            "final_cost": cost, "via_point_errors": {"via_cog1@100": via}})}

    plans = [plan(a, 0, 100.0, 0.02), plan(a, 1, 200.0, 0.03), plan(b, 0, 100.0 + 1e-9, 0.02),
             plan(b, 1, 260.0, 0.009)]
    e = nudge_effect(plans, a, b)
    assert e["seeds"] == [0, 1] and e["chaotic"] == [1] and e["cost_change"][1] == pytest.approx(0.3)
    assert e["via_change"][1] == pytest.approx(0.021)
    md = "\n".join(processor_section([{"figure": "fig3.4", "processor": [e]}]))
    assert "| fig3.4 | AICO | 1e-09 | 2 | 1 (1) | 30 % | 0.021 |" in md
    assert processor_section([{"figure": "fig3.4"}]) == []


def test_the_rows_that_do_not_hold_are_listed_with_their_reasons():
    from raico.thesis.claims import evaluate_claims
    from raico.thesis.report import not_holding_section
    from tests.thesis.test_evaluate import table

    rows = evaluate_claims(("ilqg_stalls", "raico_converges"), table(ilqg=150, r1=100, r10=120, aico=100), [],
                           "fig3.2c")
    md = not_holding_section(rows)
    assert md[0] == "### The thesis's rows that do not hold, and why" and len(md) == 4  # the beyond row left out
    assert md[2].startswith("- fig3.2c, iLQG cannot generate movement policies with low costs on the analytic model: "
                            "**does not hold**. none holds: iLQG's diverged runs 0/10 <= 0/10")


def test_the_pendulum_endings_are_said_with_their_spread_and_saturation():
    from raico.thesis.report import endings_sentence

    S = {"sigma*=0, w=0.01": {"task_error_last_by_seed": [0.00763, 0.00764], "torque_saturation_curve": [0.9, 0.29],
                              "gp_error_curve": [1.0, 2e-4]},
         "sigma*=none": {"task_error_last_by_seed": [0.00762], "torque_saturation_curve": [0.5, 0.3],
                         "gp_error_curve": [1.0, 3e-4]},
         "sigma*=1, w=100": {"task_error_last_by_seed": [2.7, 2.2]}}
    S["sigma*=0.2, w=100"] = {"task_error_last_by_seed": [2.4, 0.003]}
    text = endings_sentence(S)
    assert text.startswith("3 of the 4 endings within 0.1 rad of upright (setting and seed, last episode) lie within 1 "
                           "mrad of 0.00762 rad (from 0.00762 to 0.00764); in the settings that end there every time, "
                           "the executed torque is at its limit in 29 %-30 % of the last episode's steps")
    assert text.endswith("; the others: sigma*=0.2, w=100 seed 1 at 0.003 rad.")
    assert endings_sentence({"sigma*=1, w=100": S["sigma*=1, w=100"]}) is None


def test_a_thesis_setup_row_names_its_set_up_in_place_of_raicos():
    from raico.thesis.claims import setup_notes
    from raico.thesis.report import setup_in_place

    raico = setup_notes("aico_no_balancing", "fig3.4")
    assert "CoG weights read as 1e6" in raico and "right sole held" in raico
    row = setup_in_place(raico, "balance-thesis")
    assert row.startswith("eq. 3.7's cost") and "CoG weights read" not in row and "right sole held" not in row
    assert "q0 about a posture leaning" in row  # the start is raico's in this set-up
    assert setup_in_place(setup_notes("counterbalance", "fig3.3"), "reach-zero").startswith("q0 about the zero posture")
