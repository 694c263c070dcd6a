"""The joint-scaling bench: a solver that cannot take a chain is said (why, which size), not dropped."""

from __future__ import annotations

import json

from bench import model_files


def test_a_solver_exception_is_said_with_its_chain_size(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(model_files, "CHAIN_SIZES", (2, 3))
    real = model_files._per_iteration_detail

    def per_iteration(f, solver, options, reps=3):
        if solver == "raico" and f.name == "chain3.toml":
            return real(f, "no-such-solver", options, reps=1)   # the solver registry refuses it: an exception
        return {"seconds": 1e-3, "repeats": 0.0, "n_x": 4, "n_u": 2, "T": 100, "status": "max-iterations"}, ""

    monkeypatch.setattr(model_files, "_per_iteration_detail", per_iteration)
    rows = model_files.scaling_rows()
    out = capsys.readouterr().out
    assert "n=  3  not timed: " in out and "no-such-solver" in out
    fit = next(r for r in rows if r["benchmark"] == "R-AICO per iteration against joints")
    assert fit["joint_sizes"] == [2] and fit["joint_exponent"] is None
    assert list(fit["joint_skipped"]) == [3] and "no-such-solver" in fit["joint_skipped"][3]


def test_the_readme_block_names_the_sizes_left_out(tmp_path):
    from scripts.readme_numbers import bench_block

    row = {"benchmark": "R-AICO per iteration against joints", "joint_sizes": [2, 4, 8],
           "joint_seconds": [1e-3, 2e-3, 4e-3], "joint_exponent": 1.0, "joint_skipped": {"16": "ValueError: x"}}
    (tmp_path / "results.json").write_text(json.dumps({"results": [row]}))
    block = bench_block(tmp_path / "results.json")
    assert "| R-AICO | 2, 4, 8 |" in block and "R-AICO not timed (left out of the exponent): n = 16: ValueError: x" in block
