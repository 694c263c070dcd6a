"""bench/payload.py's page and plot from a small synthetic run (no simulation)."""

from bench import payload


def run(label, seed, dist, status="ok"):
    n = len(dist)
    return {"label": label, "seed": seed, "distance_m": dist, "level_rad": [0.03] * n,
            "planned_distance_m": [0.005] * n, "achieved": [d <= 0.01 for d in dist], "status": [status] * n,
            "plan_status": ["max-iterations"] * n, "gp_error": [2.0, 0.2][:n], "gp_error_heldout": [0.7, 0.6][:n],
            "n_points": [200, 300][:n], "data_steps": [100] * n, "fit_s": [1.0] * n, "plan_s": [5.0] * n}


def doc():
    return {"model_file": {"planned_m": 0.002, "executed_m": 0.07, "executed_level_rad": 0.1, "status": "ok"},
            "runs": [run("a", 0, [0.02, 0.008]), run("a", 1, [0.009, 0.02]), run("a", 2, [0.03, 0.02]),
                     run("b", 0, [0.009, 0.005], status="tracking-lost")],
            "settings": {"episodes": 2}, "seeds": 3, "load": "1.00 1.00 1.00"}


def test_first_within_needs_an_ok_execution_within_the_goal():
    d = doc()["runs"]
    assert [payload.first_within(r) for r in d] == [2, 1, None, None]


def test_page_counts_seeds_within_the_goal_by_the_second_episode(tmp_path):
    text = payload.page(doc())
    row_a = next(line for line in text.splitlines() if line.startswith("| a | 2 of 3 |"))
    assert "| 1.5 |" in row_a and "ok 6" in row_a and "max-iterations 6" in row_a
    assert "| b | 0 of 1 | none |" in text and "tracking-lost 2" in text
    assert "7.00 cm from the target" in text
    payload.plot(doc(), tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000
