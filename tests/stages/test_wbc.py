"""Start states that stand and the whole-body stabilizer: the inverse-kinematics stance
projection, a standing Nao under the stabilizer, the QP's contact forces, the CLI options
(real Drake, small horizons)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.plants.floating import STANCE_MARGIN, shared_floating
from raico.plants.robots import builtin_spec
from raico.stages.evaluate.metrics import STATUSES, signed_margin
from raico.stages.execute.config import ExecuteConfig
from raico.stages.execute.stage import execute
from tests.stages.test_execute_floating import desc_for, pseudo_plan
from tests.tolerance import assert_close, close, scale_of

NAO_MASS = 5.305354  # kg, as tests.stages.test_execute_floating.py
G = 9.81


@pytest.mark.numerics
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stance_projection_puts_both_soles_flat_and_the_cog_inside(seed):
    """The thesis's spread (0.05 rad) on the standing posture puts the feet uneven; the projection
    lays both soles flat on the ground (every corner within 1 mm of z = 0) with the CoG at least the
    stance margin inside their polygon, and reports its size."""
    free = shared_floating(builtin_spec("nao"))
    fixed = free.fixed
    rng = np.random.default_rng(seed)
    q = np.clip(fixed.default_q + 0.05 * rng.standard_normal(fixed.n_q), fixed.lower, fixed.upper)
    uneven, _ = free.standing_positions(q)
    free.plant.SetPositions(free.context, uneven)
    assert np.ptp(free.sole_corners(free.context)[..., 2]) > 2e-3  # the spread lifts some corner by > 2 mm
    qp, info = free.stance_positions(q)
    ctx = free.context
    free.plant.SetPositions(ctx, qp)
    corners = free.sole_corners(ctx)
    assert np.abs(corners[..., 2]).max() < 1e-3
    assert np.abs(corners[0, :, :2] - np.array([[-0.055, -0.044], [0.105, -0.044], [0.105, 0.044],
                                                [-0.055, 0.044]])).max() < 1e-3  # left sole at the origin
    poly = corners[..., :2].reshape(-1, 2)
    poly = poly[ConvexHull(poly).vertices]
    c = free.plant.CalcCenterOfMassPositionInWorld(ctx)
    assert signed_margin(poly, c[:2]) >= STANCE_MARGIN - 1e-4
    # the CoG's ground projection stays (to 5 mm) where the posture puts it on the fixed-base model,
    # the plan's world frame: a CoG via-point of the plan is still one for the robot
    from raico.plants.taskmaps import CenterOfMass

    assert np.linalg.norm(c[:2] - CenterOfMass(fixed).value_and_jacobian(q)[0][:2]) < 5e-3
    assert info["cog_margin"] == pytest.approx(signed_margin(poly, c[:2]))
    dq = free.planning_q(qp) - q
    assert info["projection_norm"] == pytest.approx(np.linalg.norm(dq)) and 0 < info["projection_norm"] < 0.5
    assert info["projection_max"] == pytest.approx(np.abs(dq).max())
    # the coupled hip stays coupled, the joints within their limits
    p = free.plant
    assert qp[p.GetJointByName("LHipYawPitch").position_start()] == pytest.approx(
        qp[p.GetJointByName("RHipYawPitch").position_start()], abs=1e-6)
    qj = qp[free.joint_idx]
    assert np.all(qj >= fixed.plant.GetPositionLowerLimits() - 1e-6)
    assert np.all(qj <= fixed.plant.GetPositionUpperLimits() + 1e-6)


@pytest.mark.numerics
def test_stabilizer_holds_a_standing_nao_for_two_seconds():
    """No motion: the stabilizer keeps the robot up for 2 s, the ground carries its weight (within
    2 %), the feet stay flat, the QP's corner forces lie inside the linearized friction cone."""
    from raico.stages.execute.wbc import CONTROL_PERIOD, LIMIT_MARGIN, MU

    nao = shared_floating(builtin_spec("nao")).fixed
    T, dt = 200, 0.01
    Q = np.tile(nao.default_q, (T + 1, 1))
    out = execute(ExecuteConfig(plan="hold", controller="wbc", start="standing"),
                  desc_for("nao", nao.default_q, T, dt), pseudo_plan(Q, dt))
    m, d = out.metrics, out.floating
    assert (m["status"], m["stood"], m["wbc_qp_failures"], m["wbc_qp_fallbacks"]) == ("ok", True, 0, 0)
    weight = NAO_MASS * G
    settled = d["sole_force"][10:].sum(axis=1)  # after 0.1 s
    assert np.allclose(settled, weight, rtol=0.02)
    assert np.abs(d["corners"][..., 2]).max() < 1e-3
    assert np.abs(d["torso_p"] - d["torso_p"][0]).max() < 2e-3
    # the largest joint error: the hands, closed at their limit 0 in the posture, held LIMIT_MARGIN open
    assert m["max_tracking_error"] < LIMIT_MARGIN + 1e-3 and m["cog_inside_fraction"] == 1.0
    f = d["wbc_corner_force"]  # (updates, 8, 3) N, world frame
    assert f.shape[1:] == (8, 3) and len(f) == pytest.approx(T * dt / CONTROL_PERIOD, abs=2)
    assert np.allclose(f[..., 2].sum(axis=1), weight, rtol=0.02)
    assert np.all(f[..., 2] >= -1e-6)
    assert np.all(np.abs(f[..., :2]) <= MU * f[..., 2:3] + 1e-6)
    assert m["start_projection_norm"] < 1e-3  # the standing posture is a stance already
    # standing still, the zero-moment point is the CoG's ground projection (to 2 mm, the hydroelastic
    # soles' settling), inside the feet with the CoG's margin; none at t = 0 (no contact results yet)
    zmp, cog = d["zmp"], d["cog"]
    assert np.all(np.isnan(zmp[0])) and np.all(np.isfinite(zmp[10:]))
    assert np.abs(zmp[10:] - cog[10:, :2]).max() < 2e-3
    assert m["zmp_edge_fraction"] == 0.0 and abs(m["zmp_min_margin"] - m["cog_min_margin"]) < 3e-3


def test_default_execution_is_the_pd_baseline():
    """The new options default to the old behaviour: no projection, no stabilizer metrics."""
    cfg = ExecuteConfig(plan="p")
    assert (cfg.normalized().start, cfg.controller) == ("plan", "pd")
    # the stabilizer starts standing unless told otherwise (it needs both soles on the ground); an explicit start stays
    assert ExecuteConfig(plan="p", controller="wbc").normalized().start == "standing"
    assert ExecuteConfig(plan="p", controller="wbc", start="plan").normalized().start == "plan"
    assert ExecuteConfig(plan="p", controller="wbc").normalized() == ExecuteConfig(plan="p", controller="wbc",
                                                                                  start="standing").normalized()
    nao = shared_floating(builtin_spec("nao")).fixed
    T, dt = 20, 0.01
    out = execute(cfg, desc_for("nao", nao.default_q, T, dt), pseudo_plan(np.tile(nao.default_q, (T + 1, 1)), dt))
    assert out.metrics["status"] == "ok"
    assert not {"start_projection_norm", "wbc_qp_failures"} & set(out.metrics)
    assert "wbc_corner_force" not in out.floating


@pytest.mark.parametrize("field, value, message", [
    ("controller", "lqr", "controller must be one of pd, wbc, mpc (got 'lqr')"),
    ("start", "crouch", "start must be one of plan, standing (got 'crouch')"),
])
def test_bad_values_of_the_new_options(field, value, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        ExecuteConfig(plan="p", **{field: value}).validate()
    res = CliRunner().invoke(app, ["execute", "--plan", "0123456789abcdef", f"--{field}", value])
    assert res.exit_code != 0
    err = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert err == [f"raico: error: {message}"], res.stderr


@pytest.mark.numerics
def test_cli_executes_a_plan_with_the_stabilizer(tmp_path):
    """`raico execute --controller wbc --start standing` end to end on a small R-AICO reach plan."""
    runner = CliRunner()

    def run_json(*args):
        res = runner.invoke(app, [str(a) for a in args])
        assert res.exit_code == 0, res.output
        return json.loads(res.stdout.strip().splitlines()[-1])

    plan = run_json("plan", "--plant", "nao", "--task", "reach", "--solver", "raico", "--iterations", 1,
                    "--no-record", "--json", "--artifacts", tmp_path)
    r = run_json("execute", "--plan", plan["key"], "--controller", "wbc", "--start", "standing", "--no-record",
                 "--json", "--artifacts", tmp_path)
    m = r["metrics"]
    assert r["status"] == m["status"] and m["status"] in STATUSES
    assert m["stood"] is True and m["wbc_qp_failures"] == 0
    assert 0 < m["start_projection_norm"] < 0.5 and m["start_projection_max"] <= m["start_projection_norm"]
    pd = run_json("execute", "--plan", plan["key"], "--no-record", "--json", "--artifacts", tmp_path)
    assert pd["key"] != r["key"] and "wbc_qp_failures" not in pd["metrics"]
    # the report's balance section: one panel and one table row per controller, from these two runs
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import Outcome
    from raico.thesis.figures import EXPERIMENTS
    from raico.thesis.report import balance_section

    outs = [Outcome("execute", x["key"], x["path"], True, x["status"], metrics=x["metrics"]) for x in (pd, r)]
    md, rows = balance_section(Cache(tmp_path), EXPERIMENTS["fig3.3"], outs, tmp_path)
    assert [(w["controller"], w["runs"], w["stood"]) for w in rows] == [("joint PD", 1, int(pd["metrics"]["stood"])),
                                                                        ("stabilizer", 1, 1)]
    assert rows[1]["zmp_min_margin"] == m["zmp_min_margin"] and (tmp_path / "balance.png").stat().st_size > 10_000
    assert "![balance](balance.png)" in md


def test_stabilized_figures_execute_each_plan_with_both_controllers(tmp_path):
    """A figure marked ``stabilized`` executes each executed variant's plan twice,
    with the joint PD from the plan's start (the thesis rows) and with the stabilizer from the standing start;
    the thesis-set execution claims read the PD runs only, the stabilizer's claim its own."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import Batch
    from raico.pipeline.engine.runner import Outcome
    from raico.thesis.claims import claim_executed_reaches, claim_stabilizer_stands
    from raico.thesis.figures import EXPERIMENTS, STABILIZER, experiment_flow

    for fid in ("fig3.3", "fig3.4-inside"):
        exp = EXPERIMENTS[fid]
        assert exp.stabilized and "stabilizer_stands" in exp.claims
        flow = experiment_flow(Cache(tmp_path), exp, quick=True, record=False)
        plans = next(flow)
        assert isinstance(plans, Batch) and plans.kind == "plan"
        fake = [Outcome("plan", f"{i:016x}", str(tmp_path), False, "converged") for i in range(len(plans.jobs))]
        execs = flow.send(fake)
        cfgs = [job.arg[2] for job in execs.jobs]
        executed = sum(v.seed_count(exp.seeds, True) for v in exp.variants if v in exp.execute)
        stab = [c for c in cfgs if (c.controller, c.normalized().start) == (STABILIZER["controller"], STABILIZER["start"])
                and c.x0_noise == 0 and c.process_noise == 0]
        noisy = [c for c in cfgs if c.controller == STABILIZER["controller"] and (c.x0_noise or c.process_noise)]
        assert len(noisy) == executed and {c.plan for c in noisy} == {c.plan for c in stab}  # the noise sweep
        plain = [c for c in cfgs if (c.controller, c.normalized().start) == ("pd", "plan") and c.x0_noise == 0 and c.process_noise == 0]
        # the sweep's level 0 is the figure's own execution: the same config (one cache entry, run once)
        assert len(set(stab)) == executed and len(plain) >= executed
        assert {c.plan for c in stab} <= {c.plan for c in plain}
    pd = {"status": "fell", "via_point_errors": {"via_hand@100": 0.001}}
    wbc = {"status": "ok", "controller": "wbc", "start": "standing", "via_point_errors": {"via_hand@100": 0.001}}
    assert claim_executed_reaches({}, [pd, wbc])[3] is False       # the PD run fell: the stabilizer's does not count
    assert claim_stabilizer_stands({}, [pd, wbc])[3] is True


@pytest.mark.numerics
def test_clamp_to_polygon_is_the_nearest_point_of_the_polygon():
    """The stabilizer's CoG clamp against Dykstra's alternating projections run to convergence (an
    independent method) on random polygons; a point inside comes back unchanged; a point beyond a
    corner lands on the corner."""
    from raico.stages.execute.wbc import clamp_to_polygon

    def dykstra(p, A, b, iterations=2000):
        x, y = p.copy(), np.zeros((len(b), 2))
        for _ in range(iterations):
            for i in range(len(b)):
                z = x + y[i]
                x_new = z - max(A[i] @ z - b[i], 0.0) * A[i]
                y[i], x = z - x_new, x_new
        return x

    rng = np.random.default_rng(0)
    for _ in range(40):
        eq = ConvexHull(0.1 * rng.normal(size=(8, 2))).equations
        A, b = eq[:, :2], -eq[:, 2] - 0.01
        p = 0.2 * rng.normal(size=2)
        got = clamp_to_polygon(p, A, b)
        assert np.all(A @ got <= b + 1e-9)
        assert close(got, p if np.all(A @ p <= b) else dykstra(p, A, b), scale=scale_of(p, b))
    A, b = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]), np.ones(4)   # the square |x|, |y| <= 1
    assert np.array_equal(clamp_to_polygon(np.array([0.3, -0.2]), A, b), [0.3, -0.2])
    assert np.allclose(clamp_to_polygon(np.array([3.0, 2.0]), A, b), [1.0, 1.0])
    assert np.allclose(clamp_to_polygon(np.array([0.5, 4.0]), A, b), [0.5, 1.0])


@pytest.mark.numerics
def test_zmp_metrics_on_synthetic_margins():
    """The ZMP criteria on margins whose answer is known: the samples without a ZMP left out."""
    from raico.stages.evaluate.metrics import ZMP_EDGE, point_margins, zmp_metrics

    m = zmp_metrics(np.array([np.nan, 0.03, 0.02, ZMP_EDGE / 2, -0.01]))
    assert m == {"zmp_min_margin": -0.01, "zmp_edge_fraction": 0.5}
    assert np.isnan(zmp_metrics(np.full(3, np.nan))["zmp_min_margin"]) and zmp_metrics(None) == {}
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    out = point_margins([square, square, np.zeros((0, 2))], np.array([[0.5, 0.2], [1.5, 0.5], [0.5, 0.5]]))
    assert np.allclose(out[:2], [0.2, -0.5]) and np.isnan(out[2])


@pytest.mark.numerics
def test_single_support_metric_and_claim_on_synthetic_runs():
    """The lift metric and the single-support claim on inputs whose verdict is known."""
    from raico.stages.evaluate.metrics import LIFT, single_support_lift
    from raico.thesis.claims import claim_single_support_stands

    corners = np.zeros((10, 2, 4, 3))
    corners[5:, 1, :, 2] = [LIFT + 0.001, LIFT + 0.002, LIFT + 0.003, LIFT + 0.004]
    assert single_support_lift(corners, 5) == {"r_sole_lift": LIFT + 0.001, "lifted": True}
    assert single_support_lift(corners, 4)["lifted"] is False        # still on the ground at step 4
    corners[7, 1, 0, 2] = np.nan
    assert single_support_lift(corners, 5)["r_sole_lift"] == -np.inf
    run = {"status": "ok", "controller": "wbc", "lifted": True, "r_sole_lift": 0.024,
           "via_point_errors": {"via_cog1@100": 0.002}}
    assert claim_single_support_stands({}, [run] * 3)[3] is True
    assert claim_single_support_stands({}, [run, {**run, "lifted": False, "r_sole_lift": 0.019}])[3] is False
    assert claim_single_support_stands({}, [run, {**run, "status": "fell"}])[3] is False
    assert claim_single_support_stands({}, [{**run, "controller": "pd"}])[3] is False   # no stabilizer runs


@pytest.mark.numerics
def test_stabilizer_balances_a_single_support_plan_on_the_left_foot(tmp_path):
    """`raico plan --balance single` then `raico execute --controller wbc`: the stabilizer releases the right
    sole once the CoG is over the left one (its ground force about 0 from then on, 0 once lifted), the robot
    stands with status ok and the right sole lifted at least 2 cm from the plan's lift step on."""
    runner = CliRunner()

    def run_json(*args):
        res = runner.invoke(app, [str(a) for a in args])
        assert res.exit_code == 0, res.output
        return json.loads(res.stdout.strip().splitlines()[-1])

    plan = run_json("plan", "--plant", "nao", "--task", "balance-inside", "--balance", "single", "--balance-margin",
                    0.025, "--solver", "raico", "--alpha", 1, "--iterations", 25, "--seed", 1, "--no-record", "--json",
                    "--artifacts", tmp_path)
    r = run_json("execute", "--plan", plan["key"], "--controller", "wbc", "--start", "standing", "--no-record",
                 "--json", "--artifacts", tmp_path)
    m = r["metrics"]
    assert (m["status"], m["wbc_qp_failures"], m["lifted"]) == ("ok", 0, True) and m["r_sole_lift"] >= 0.02
    t_rel = m["wbc_release_time"]
    assert t_rel is not None and t_rel >= 0.2 - 1e-9
    d = np.load(Path(r["path"]) / "rollout.npz")
    after = d["times"] > t_rel + 0.05
    # released, the right sole hovers at the ground until the plan's lift step (T/3): a graze of at most 1 % of the
    # weight, none once it is lifted; the left sole carries the robot
    lifted = d["times"] >= 1.0 + 0.05
    assert np.all(d["sole_force"][after, 1] < 0.01 * NAO_MASS * G) and np.all(d["sole_force"][lifted, 1] == 0.0)
    assert np.all(d["sole_force"][after, 0] > 0.9 * NAO_MASS * G)
    assert m["zmp_edge_fraction"] == 0.0


@pytest.mark.numerics
def test_proxqp_solves_the_stabilizers_programs_as_clarabel_does():
    """The stabilizer's solver (proxsuite, warm-started) against Drake's Clarabel (an interior-point method) on
    the programs of a standing Nao and of a moving one (random joint velocities, a CoG reference off the
    current CoG): the same accelerations (the forces are unique only up to the small force regularization,
    so the check is on the cost and the constraints), every constraint met to 1e-7."""
    from raico.plants.floating import load_floating
    from raico.stages.execute.wbc import ClarabelProgram, ProxQP, make_stabilizer

    free = load_floating(builtin_spec("nao"), pd=False)
    fixed = free.fixed
    T = 100
    X = np.tile(np.r_[fixed.default_q, np.zeros(fixed.n_q)], (T + 1, 1))
    step = 0.05 * np.random.default_rng(0).standard_normal(fixed.n_q)
    X[:, :fixed.n_q] = np.clip(X[:, :fixed.n_q] + np.linspace(0, 1, T + 1)[:, None] * step, fixed.lower, fixed.upper)
    stab = make_stabilizer(free, X, 0.01)
    qp0, _ = free.stance_positions(fixed.default_q)
    rng = np.random.default_rng(1)
    nv = free.plant.num_velocities()
    programs = [stab.program(0.0, qp0, np.zeros(nv))[0]]
    for k in range(1, 6):
        v = np.zeros(nv)
        v[6:] = 0.3 * rng.standard_normal(nv - 6)
        programs.append(stab.program(0.1 * k, qp0, v)[0])
    prox = ProxQP(len(programs[0].g), len(programs[0].beq), len(programs[0].l))
    clarabel = ClarabelProgram(len(programs[0].g), len(programs[0].beq), len(programs[0].l))
    for d in programs:
        x, ok, status = prox.solve(d)
        y, ok_c, _ = clarabel.solve(d)
        assert ok and ok_c and status.endswith("PROXQP_SOLVED")
        cx, cy = (0.5 * z @ d.H @ z + d.g @ z for z in (x, y))
        assert abs(cx - cy) <= 1e-6 * max(1.0, abs(cy))
        assert np.abs(x[:nv] - y[:nv]).max() < 1e-3
        assert np.abs(d.Aeq @ x - d.beq).max() < 1e-7
        assert np.all(d.C @ x <= d.u + 1e-7) and np.all(d.C @ x >= d.l - 1e-7)
        assert np.all(x <= d.ub + 1e-7) and np.all(x >= d.lb - 1e-7)
    assert prox.fallbacks == 0


@pytest.mark.numerics
def test_stabilizer_noise_is_torque_noise_clamped_at_the_effort_limits():
    """Process noise under the stabilizer is added to its held torques and the sum clamped at the effort
    limits (as the plant clamps the PD's total): the applied torques never exceed them, and they differ
    from the noise-free run's."""
    nao = shared_floating(builtin_spec("nao")).fixed
    T, dt = 30, 0.01
    Q = np.tile(nao.default_q, (T + 1, 1))
    runs = [execute(ExecuteConfig(plan="hold", controller="wbc", start="standing", process_noise=w, seed=3),
                    desc_for("nao", nao.default_q, T, dt), pseudo_plan(Q, dt)) for w in (0.0, 0.5)]
    free = shared_floating(builtin_spec("nao"))
    limit = np.abs(free.A).T @ free.effort  # per planning joint (the coupled hip: both actuators)
    for out in runs:
        assert np.all(np.abs(out.tau) <= limit + 1e-9)
    assert runs[1].metrics["torque_saturation"] > 0 and not np.allclose(runs[0].U, runs[1].U)
    # the hands' 0.29 N m and the wrists' 0.41 N m motors clamp the 0.5 N m noise in most steps (reported on its
    # own); the stabilizer's command itself stays within the effort limits (its program's bounds), and only where
    # it asks for a whole limit is the execution at one (the limits status judges the controller's command)
    assert runs[0].metrics["effort_clamped_fraction"] == 0.0 and runs[1].metrics["effort_clamped_fraction"] > 0.5
    assert runs[0].metrics["status"] == "ok" and not runs[0].effort_at_limit.any()
    # without noise the command the limits judge is the torque the plant applied in each sample's last step
    assert_close(runs[0].floating["torque_asked"] @ free.A, runs[0].tau)
    for out in runs:
        asked = out.floating["torque_asked"]
        assert np.all(np.abs(asked) <= free.effort + 1e-6)
        np.testing.assert_array_equal(out.effort_at_limit, (np.abs(asked) >= free.effort * (1 - 1e-9)) @ free.A > 0)


@pytest.mark.numerics
def test_disturbance_observer_recovers_a_known_joint_torque():
    """The stabilizer's observer on a state reached from the last one under a known joint torque disturbance ``w``
    (besides its own command and the contact forces): its estimate is ``w`` exactly (to the fixed point's 1e-9),
    none on a joint within its margin of a limit (the hands, closed at 0), and the next program's torque map
    compensates it (``u = At x + h_j - w``, the torque bounds shifted by it)."""
    from raico.plants.floating import load_floating
    from raico.stages.execute.wbc import LIMIT_MARGIN_OBS, make_stabilizer

    free = load_floating(builtin_spec("nao"), pd=False)
    fixed, plant = free.fixed, free.plant
    X = np.tile(np.r_[fixed.default_q, np.zeros(fixed.n_q)], (11, 1))
    stab = make_stabilizer(free, X, 0.01)
    q, _ = free.stance_positions(fixed.default_q)
    nv = plant.num_velocities()
    rng = np.random.default_rng(4)
    B = plant.MakeActuationMatrix()
    v_prev = 0.05 * rng.standard_normal(nv)
    u_prev = 0.3 * rng.uniform(-1, 1, B.shape[1]) * free.effort
    w = 0.5 * rng.uniform(-1, 1, B.shape[1]) * free.effort
    tau_c = rng.standard_normal(nv)
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    M = plant.CalcMassMatrix(ctx)
    dt = 4e-3
    v = v_prev.copy()
    for _ in range(50):  # the implicit step M (v - v_prev)/dt = B (u + w) + tau_c - h(q, v), by fixed point
        plant.SetVelocities(ctx, v)
        h = plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
        v = v_prev + dt * np.linalg.solve(M, B @ (u_prev + w) + tau_c - h)
    plant.SetVelocities(ctx, v)
    h = plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
    jv = np.array([np.flatnonzero(B[:, a])[0] for a in range(B.shape[1])])  # each actuator's velocity
    d, (At, hj) = stab.program(0.1, q, v, (v_prev, dt, tau_c, u_prev))
    w_hat = h[jv] - hj
    qj = q[jv + 1]  # joint positions: the floating base has 7 positions and 6 velocities
    lower, upper = plant.GetPositionLowerLimits()[jv + 1], plant.GetPositionUpperLimits()[jv + 1]
    near = (qj <= lower + LIMIT_MARGIN_OBS) | (qj >= upper - LIMIT_MARGIN_OBS)
    assert near.any() and not near.all()
    np.testing.assert_allclose(w_hat[~near], w[~near], atol=1e-9)
    assert np.all(w_hat[near] == 0.0)
    n_act = B.shape[1]
    assert_close(d.u[:n_act], free.effort - hj, scale=scale_of(free.effort, hj))   # N m
    assert_close(d.l[:n_act], -free.effort - hj, scale=scale_of(free.effort, hj))
    _, (_, hj0) = stab.program(0.1, q, v)  # no observer: no compensation
    assert_close(hj0, h[jv], scale=scale_of(h))


@pytest.mark.numerics
def test_stabilizer_execution_is_repeatable_in_one_process():
    """The same noisy execution twice in one process gives the same numbers, bit for bit: the stabilizer
    loads proxsuite's portable build (its AVX2 build's results depend on where its work arrays lie in
    memory: two identical executions of a fig3.4 plan differed from the first program on)."""
    from raico.stages.execute.wbc import portable_proxsuite

    loaded = portable_proxsuite()
    import proxsuite  # any later import in the process gets the same build

    assert loaded is proxsuite and proxsuite._submodule.__name__ == "proxsuite.proxsuite_pywrap"
    nao = shared_floating(builtin_spec("nao")).fixed
    T, dt = 100, 0.01
    Q = np.tile(nao.default_q, (T + 1, 1))
    cfg = ExecuteConfig(plan="hold", controller="wbc", start="standing", x0_noise=0.02, process_noise=0.5, seed=4)
    runs = [execute(cfg, desc_for("nao", nao.default_q, T, dt), pseudo_plan(Q, dt)) for _ in range(3)]
    for other in runs[1:]:
        for key in ("X", "q_free", "wbc_corner_force"):
            a, b = runs[0].arrays()[key], other.arrays()[key]
            assert np.array_equal(a, b, equal_nan=True), key
        assert other.metrics["wbc_qp_fallbacks"] == runs[0].metrics["wbc_qp_fallbacks"]
