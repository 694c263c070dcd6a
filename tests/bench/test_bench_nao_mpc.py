"""bench.nao_mpc's held-out page: the counts, statuses and falls of each variant, from synthetic runs."""

from __future__ import annotations

from bench.nao_mpc import lead_markdown, per_seed


def _row(variant: str, seed: int, stood: bool, tick: float | None) -> dict:
    return {"variant": variant, "seed": seed, "execute.status": "ok" if stood else "fell",
            "execute.stood": stood, "execute.failure_time": None if stood else 2.25,
            "execute.mpc_median_tick_s": tick, "execute.mpc_p99_tick_s": None if tick is None else 2 * tick}


def test_held_out_page_counts_each_variant() -> None:
    rows = [_row("plan + stabilizer", s, s % 2 == 0, None) for s in range(10, 14)]
    rows += [_row("MPC ahead", s, s != 13, 0.02) for s in range(10, 14)]
    page = lead_markdown(per_seed(rows), (1.0, 2.0))
    assert "seeds 10-13" in page
    assert "| plan + stabilizer | 2 of 4 | fell 2, ok 2 | 2.25 2.25 | - |" in page
    assert "| MPC ahead | 3 of 4 | fell 1, ok 3 | 2.25 | 20.0 / 40.0 |" in page
