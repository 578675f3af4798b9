"""Locking study (issue 5): coarse P1 / P2 / P2-P0 Diamonds against a mesh-converged reference.

For each robot (softforce's default Diamond and SOFA's own meshes) and each load case (the
robot file's gravity with the cables held at 0 mm, then each cable pulled 10 mm alone, with
gravity), every model is solved to static equilibrium and its surface compared with the
reference: the displacement of each free surface node of the model's mesh against the
reference's displacement at the same material point (the point attached to the reference
mesh with the reference's shape functions). The reference is P2-P0 on the finest mesh; P2
on the same mesh and the change from the next coarser P2-P0 mesh say how converged it is.

    python benchmarks/study_locking.py    # about 2 hours on a 2-core machine
    python benchmarks/study_locking.py --reduced    # the reduced model's rows alone

Equilibria are cached in out/study_locking/ (delete it to recompute); the script writes
docs/locking.md and docs/locking_convergence.png. --reduced compares the reduced p2 models
of benchmarks/bench_reduced.py (trained there when missing) with the same references and
rewrites only their section of docs/locking.md (about 15 minutes with the references to
solve, seconds once they are cached).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from benchmarks.bench_fem import update_timing
from softforce_cli.fem.allocator import keep_freed_memory
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.io.atomic import atomic_write_text
from softforce_cli.model.config import load_config
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.mesh_io import read_tet_mesh
from softforce_cli.model.procedural import diamond_mesh
from softforce_cli.model.robot import Robot, build_robot

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "study_locking"
DEFAULT_ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
SOFA = ROOT.parent / "shared" / "robots" / "diamond"
PULL_MM = 10.0
CABLES = ("north", "west", "south", "east")
CASES = {"gravity": np.zeros(4)} | {
    f"{name} {PULL_MM:g} mm": PULL_MM * np.eye(4)[i] for i, name in enumerate(CABLES)
}
# Mesh sizes (gmsh Mesh.MeshSizeMax, mm) of the default robot; 8.5 and 4.8 are the sample
# data's coarse and fine meshes.
DEFAULT_SIZES_MM = (12.0, 8.5, 6.5, 4.8, 3.6)
COARSE_SIZE_MM, REFERENCE_SIZE_MM = 8.5, 4.8
COARSE_MESH = {"default": f"h{COARSE_SIZE_MM:g}", "sofa": "4k"}


@dataclasses.dataclass(frozen=True)
class Level:
    """One robot model: a mesh of a robot with an element type."""

    robot_name: str  # "default" or "sofa"
    mesh_label: str  # e.g. "h8.5" or "4k"
    element: str

    @property
    def key(self) -> str:
        return f"{self.robot_name}_{self.mesh_label}_{self.element}"


def _robot(level: Level) -> Robot:
    if level.robot_name == "default":
        config = load_config(DEFAULT_ROBOT)
        mesh = TetMesh(*diamond_mesh(mesh_size_mm=float(level.mesh_label[1:])))
    else:
        config = load_config(SOFA / "diamond.toml")
        path = SOFA / f"diamond_{level.mesh_label}_tet.vtu"
        config = dataclasses.replace(config, mesh=dataclasses.replace(config.mesh, path=path))
        spec = config.mesh
        mesh = read_tet_mesh(spec.path, spec.scale, spec.rotation_deg, spec.translation_mm)
    config = dataclasses.replace(config, mesh=dataclasses.replace(config.mesh,
                                                                  element=level.element))
    return build_robot(config, mesh)


def equilibria(level: Level, log) -> tuple[Robot, dict[str, np.ndarray]]:
    """The robot and its equilibrium positions (N, 3) per load case, cached on disk."""
    robot = _robot(level)
    path = CACHE / f"{level.key}.npz"
    if path.exists():
        with np.load(path) as data:
            return robot, {case: data[case] for case in CASES}
    start = time.perf_counter()
    positions = {}
    gravity = None
    for case, actuation in CASES.items():
        solved = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation),
                                   start_mm=gravity)
        positions[case] = solved.positions_mm
        gravity = positions["gravity"]
    log(f"{level.key}: {len(robot.fe_model.free_dofs)} dofs, "
        f"{time.perf_counter() - start:.0f} s")
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, **positions)
    return robot, positions


def surface_difference(model: Robot, model_mm: np.ndarray,
                       references: list[tuple[Robot, np.ndarray]]) -> tuple[float, float]:
    """RMS and max (mm) over the model's free surface nodes of |u_model - u_reference|, with
    u_reference the mean displacement of the reference models (robot, positions) there."""
    nodes = np.setdiff1d(model.mesh.surface_nodes, model.fixed_nodes)
    rest = model.mesh.nodes_mm[nodes]
    u_model = model_mm[nodes] - rest
    u_reference = np.zeros_like(rest)
    for reference, reference_mm in references:
        attached = reference.attach(rest)
        u_reference += (attached.positions(reference_mm)
                        - attached.positions(reference.rest_nodes_mm)) / len(references)
    distance = np.linalg.norm(u_model - u_reference, axis=1)
    return float(np.sqrt(np.mean(distance**2))), float(distance.max())


def apex_sag_mm(robot: Robot, positions_mm: np.ndarray) -> float:
    apex = robot.marker_points.subset(np.array([robot.marker_ids.index("apex")]))
    return float(-(apex.positions(positions_mm) - apex.positions(robot.rest_nodes_mm))[0, 2])


def levels_of(robot_name: str) -> tuple[list[Level], Level]:
    """The compared models and the reference of a robot."""
    if robot_name == "sofa":
        compared = [Level("sofa", mesh, element) for mesh in ("4k", "34k")
                    for element in ("p1", "p2", "p2-p0")]
        reference = Level("sofa", "34k", "p2-p0")
    else:
        compared = [Level("default", f"h{s:g}", e) for s in DEFAULT_SIZES_MM
                    for e in ("p1", "p2", "p2-p0")
                    if e == "p1" or s >= REFERENCE_SIZE_MM]  # P2 on 3.6 mm: too long
        reference = Level("default", f"h{REFERENCE_SIZE_MM:g}", "p2-p0")
    return [level for level in compared if level != reference], reference


def study(robot_name: str, log) -> list[dict]:
    """Rows per model: RMS, max and apex sag per case against the reference; on the coarse
    mesh also the RMS range against plain P2 on the reference mesh and against the midpoint
    of the two (when P2 there has been solved)."""
    compared, reference_level = levels_of(robot_name)
    reference = equilibria(reference_level, log)
    other_level = dataclasses.replace(reference_level, element="p2")
    other = (equilibria(other_level, log)
             if other_level in compared or (CACHE / f"{other_level.key}.npz").exists() else None)
    rows = []
    for level in [*compared, reference_level]:
        robot, positions = equilibria(level, log)
        row = {"level": level, "tets": robot.mesh.tet_count,
               "dofs": len(robot.fe_model.free_dofs), "cases": {}, "against": {}}
        for case in CASES:
            rms, worst = surface_difference(robot, positions[case],
                                            [(reference[0], reference[1][case])])
            row["cases"][case] = (rms, worst, apex_sag_mm(robot, positions[case]))
        if level.mesh_label == COARSE_MESH[robot_name] and other is not None:
            for label, references in (("P2", [other]), ("midpoint", [reference, other])):
                row["against"][label] = [
                    surface_difference(robot, positions[case],
                                       [(r, mm[case]) for r, mm in references])[0]
                    for case in CASES]
        rows.append(row)
    return rows


def table(rows: list[dict]) -> list[str]:
    head = "| mesh | element | tets | free dofs | " + " | ".join(
        f"{case}: RMS / max (mm)" for case in CASES) + " | apex sag, gravity (mm) |"
    lines = [head, "|" + "---|" * (5 + len(CASES))]
    for row in rows:
        level = row["level"]
        cells = [f"{rms:.2f} / {worst:.2f}" for rms, worst, _ in row["cases"].values()]
        element = level.element + (" (reference)" if row is rows[-1] else "")
        lines.append(f"| {level.mesh_label} | {element} | {row['tets']} | {row['dofs']} | "
                     + " | ".join(cells) + f" | {row['cases']['gravity'][2]:.2f} |")
    return lines


def plot(results: dict[str, list[dict]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4.5), dpi=110,
                                squeeze=False)
    for ax, (name, rows) in zip(axes[0], results.items(), strict=True):
        for element, marker in (("p1", "o"), ("p2", "s"), ("p2-p0", "^")):
            points = sorted((r["dofs"], np.mean([c[0] for c in r["cases"].values()]))
                            for r in rows[:-1] if r["level"].element == element)  # not the ref
            if points:
                ax.loglog(*zip(*points, strict=True), marker=marker, label=element)
        ax.axhline(1.0, color="grey", ls="--", lw=1, label="1 mm target")
        ax.set(xlabel="free dofs", ylabel="surface RMS vs P2-P0 finest (mm), mean of 5 cases",
               title=f"{name} Diamond")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def summary(results: dict[str, list[dict]]) -> list[str]:
    """One line per robot and element on its coarse mesh: RMS range over the load cases
    against the reference (P2-P0, finest mesh), plain P2 on that mesh, and their midpoint."""
    lines = ["| robot, coarse mesh | element | surface RMS (mm) vs P2-P0 fine: 5 cases | "
             "worst max | vs P2 fine | vs midpoint | apex sag, gravity (reference) |",
             "|---|---|---|---|---|---|---|"]

    def span(values) -> str:
        return f"{min(values):.2f} to {max(values):.2f}" if values else "not solved"

    for name, rows in results.items():
        reference = rows[-1]  # study() puts the reference last
        for row in rows:
            if row["level"].mesh_label != COARSE_MESH[name]:
                continue
            worst = max(c[1] for c in row["cases"].values())
            lines.append(f"| {name}, {row['tets']} tets | {row['level'].element} | "
                         f"{span([c[0] for c in row['cases'].values()])} | {worst:.2f} | "
                         f"{span(row['against'].get('P2', []))} | "
                         f"{span(row['against'].get('midpoint', []))} | "
                         f"{row['cases']['gravity'][2]:.2f} "
                         f"({reference['cases']['gravity'][2]:.2f}) |")
    return lines


REDUCED_BEGIN, REDUCED_END = "<!-- reduced model rows -->", "<!-- end reduced model rows -->"


def reduced_section(log) -> str:
    """The reduced model's section of docs/locking.md (between its markers): the reduced p2
    models of benchmarks/bench_reduced.py (the default robot's coarse mesh, 200 modes) and
    their full p2 model against the default robot's references, as summary() reads the
    coarse models, and each reduced model against its full one."""
    from benchmarks.bench_reduced import FAST_SETTINGS, SETTINGS, reduced_robot

    _, reference_level = levels_of("default")
    reference = equilibria(reference_level, log)
    other = equilibria(dataclasses.replace(reference_level, element="p2"), log)
    lines = ["| model, coarse default mesh | surface RMS (mm) vs P2-P0 fine: 5 cases | worst "
             "max | vs P2 fine | vs midpoint | apex sag, gravity (reference) | vs its full "
             "p2 model |", "|---|---|---|---|---|---|---|"]
    def solved(robot: Robot) -> dict[str, np.ndarray]:
        return {case: solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation)
                                        ).positions_mm for case, actuation in CASES.items()}

    models = {f"ECSW {SETTINGS.ecsw_tolerance:g}": reduced_robot(settings=SETTINGS),
              f"ECSW {FAST_SETTINGS.ecsw_tolerance:g}": reduced_robot(settings=FAST_SETTINGS,
                                                                     stem="diamond_p2_fast")}
    full = next(iter(models.values()))[0]  # the same full robot under both
    full_mm = solved(full)
    lines.append(_reduced_row("full p2", full, full_mm, reference, other, None))
    for label, (_, reduced) in models.items():
        info = reduced.fe_model.reduction.info
        lines.append(_reduced_row(f"reduced p2, {info['modes']} modes, {label} "
                                  f"({info['sampled_points']} points)", reduced,
                                  solved(reduced), reference, other, (full, full_mm)))
    log(f"reduced rows: {len(lines) - 2}")
    return "\n".join([REDUCED_BEGIN, *lines, REDUCED_END])


def _reduced_row(label: str, robot: Robot, positions: dict[str, np.ndarray],
                 reference: tuple[Robot, dict], other: tuple[Robot, dict],
                 full: tuple[Robot, dict] | None) -> str:
    def span(values) -> str:
        return f"{min(values):.2f} to {max(values):.2f}"

    against = {name: [surface_difference(robot, positions[case],
                                         [(r, mm[case]) for r, mm in references])
                      for case in CASES]
               for name, references in (("reference", [reference]), ("P2", [other]),
                                        ("midpoint", [reference, other]))}
    to_full = "-" if full is None else span([
        surface_difference(robot, positions[case], [(full[0], full[1][case])])[0]
        for case in CASES])
    return (f"| {label} | {span([rms for rms, _ in against['reference']])} | "
            f"{max(worst for _, worst in against['reference']):.2f} | "
            f"{span([rms for rms, _ in against['P2']])} | "
            f"{span([rms for rms, _ in against['midpoint']])} | "
            f"{apex_sag_mm(robot, positions['gravity']):.2f} "
            f"({apex_sag_mm(reference[0], reference[1]['gravity']):.2f}) | {to_full} |")


def write_reduced_section(section: str, docs: Path) -> None:
    """Replace the reduced model's section of docs/locking.md (the rest is kept)."""
    path = docs / "locking.md"
    text = path.read_text()
    head, rest = text.split(REDUCED_BEGIN)
    _, tail = rest.split(REDUCED_END)
    atomic_write_text(path, head + section + tail, force=True)


def write_report(results: dict[str, list[dict]], rates: dict[str, tuple], reduced: str,
                 docs: Path) -> None:
    """docs/locking.md: the measured tables (the prose around them is in REPORT)."""
    sections = []
    for name, rows in results.items():
        title = {"default": "softforce's default Diamond (procedural, gmsh sizes in mm)",
                 "sofa": "SOFA's Diamond meshes (4k and 34k tetrahedra)"}[name]
        sections += [f"### {title}", "", *table(rows), ""]
    speed = ["| element | tets | update | rate | K assembly | factorisation | free dofs |",
             "|---|---|---|---|---|---|---|"]
    for element, (update_s, assemble_s, factor_s, robot) in rates.items():
        speed.append(f"| {element} | {robot.mesh.tet_count} | {update_s * 1e3:.0f} ms | "
                     f"{1 / update_s:.1f} Hz | "
                     f"{assemble_s * 1e3:.0f} ms | {factor_s * 1e3:.0f} ms | "
                     f"{len(robot.fe_model.free_dofs)} |")
    text = REPORT.format(cases=", ".join(CASES), tables="\n".join(sections),
                         speed="\n".join(speed), summary="\n".join(summary(results)),
                         date=time.strftime("%Y-%m-%d"), reduced=reduced)
    (docs / "locking.md").write_text(text)
    plot(results, docs / "locking_convergence.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="default,sofa")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    parser.add_argument("--reduced", action="store_true",
                        help="only the reduced model's section of docs/locking.md")
    args = parser.parse_args()
    keep_freed_memory()

    def log(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    if args.reduced:
        write_reduced_section(reduced_section(log), args.docs)
        return

    results = {}
    for name in args.robots.split(","):
        if name == "sofa" and not (SOFA / "diamond.toml").exists():
            log(f"skipping SOFA's meshes: {SOFA} not present")
            continue
        results[name] = study(name, log)
    rates = {element: update_timing(element, repeats=5) for element in ("p1", "p2", "p2-p0")}
    coarser = Level("default", "h12", "p2-p0")
    rates["p2-p0 on the 12 mm mesh"] = update_timing("p2-p0", 5, _robot(coarser))
    write_report(results, rates, reduced_section(log), args.docs)


REPORT = """# Volumetric locking and the element choice (issue 5)

Written by `python benchmarks/study_locking.py` on {date} (about 2 hours on a 2-core
machine, most of it the P2 solves on SOFA's 34k mesh; equilibria cached in
out/study_locking/). Tables and figure are generated; the
text interprets the run recorded in the project's history.

## Summary

{summary}

- **P1 is far from converged on this robot**, in bending as much as in volume. The coarse P1
  Diamond is 6-8 mm RMS from the reference and sags half as much under its own weight; even
  P1 on 38k tetrahedra (default robot, 3.6 mm) is still 4-5.6 mm RMS away. The issue's
  "2-4 mm" compared P1 with a 34k-tet P1 model, which locks too: against a quadratic
  reference the gap is about twice that.
- **Quadratic elements on the same coarse mesh cut that to about 1 mm RMS** (6 to 10 times
  less), under gravity and under each cable, with every law. Both options are quadratic
  10-node tetrahedra built on the input mesh (mid-edge nodes appended after the mesh's):
  `element = "p2"` (full 4-point integration) and `element = "p2-p0"` (the law's lambda
  terms at the centroid: for the linear law the condensed mixed P2 / P0-pressure method;
  for corotational and Neo-Hookean the same split psi = psi_mu + psi_lambda).
- **The reference has an uncertainty of about 0.3 mm RMS, and the verdict on the 1 mm target
  depends on it.** P2 and P2-P0 on the finest mesh differ by 0.44-0.59 mm RMS (both robots,
  all cases). They bracket the converged solution: plain P2 still locks mildly at nu = 0.45
  and is too stiff, P2-P0 is slightly too soft (cantilever on 40 x 4 x 4 cells: -0.4% and
  +0.5% of the converged 3D value), so their midpoint is the best estimate, with half their
  difference as its uncertainty.
- **`p2` meets the target on both robots' coarse meshes against that best estimate**: 0.88
  to 1.06 mm RMS on the default robot and 0.66-0.79 mm on SOFA's 4k mesh (worst point 2.6
  and 2.0 mm). `p2-p0` is more accurate on the default robot (0.55-1.01 mm) but too soft on
  SOFA's coarser mesh (1.67-1.97 mm; apex sag 13.2 mm against 12.4 mm for the P2-P0
  reference and 11.7 mm for P2 on 34k tets), as on a cantilever with a single cell across
  its section (10 x 1 x 1 cells: 13% too soft): the one-point volumetric constraint is too
  weak on meshes with few elements across a bar. P2 is the conforming, monotonically
  converging option and the one to choose; P2-P0 is the more accurate one on meshes with a
  few elements across every bar.
- **Cantilever** (tests/test_p2.py; 100 x 10 x 10 mm, nu = 0.45, 10 x 2 x 2 cells = 240
  tets, tip load, ratio to Timoshenko): P1 0.236, P2 0.944, P2-P0 0.998; the mesh-converged
  3D value is 0.983 (the clamped face cannot contract sideways). P2 on 20 x 2 x 2 cubic
  cells: 0.969.
- **Speed** (below): one FE update with P2 or P2-P0 on the coarse robot cost about 20 times
  P1's with the first solver (1.3-1.5 Hz instead of 26-31 Hz on this shared 2-core
  machine), three quarters of it the LDL^T factorisation of 26k dofs by qdldl (a
  non-supernodal LDL^T). The factorisation is now CHOLMOD's supernodal Cholesky (through
  cvxopt; docs/fem.md), made exact for the Diamond's slightly indefinite tangent under
  gravity by springs at a few anchor dofs and a Woodbury correction: 5.9x (P2) and 7.6x
  (P2-P0) faster than qdldl on the coarse P2 stiffness, which makes the whole P2 update
  4.3x faster (2.0 s -> 0.47 s of CPU on a heavily loaded machine, where qdldl's update
  took 3x its wall time of the table below: about 6 Hz on a quiet one, an estimate). K's
  assembly (150-180 ms of CPU there, 80-100 ms wall) is now the largest part, with the
  corotational law's tangent at 18k quadrature points half of it. **`p1` stays the
  default** for the real-time sensing loop; choose `p2` (or `p2-p0` on meshes with a few
  elements across every bar) where accuracy matters more than the frame rate: offline
  calibration and diagnosis fits, synthetic ground truth (`softforce simulate`'s sample
  truth is P2 on the 6.5 mm mesh, docs/scenarios.md). P2-P0 on the 12 mm mesh (2.4k tets)
  is still within 1 mm RMS of the P2-P0 reference (0.64-0.98) at 2.9-3.5 Hz with qdldl.
- **Stability under gravity**: with a locking-free element the default Diamond, held by
  its cables at 0 mm under its own weight, has an indefinite tangent (W_aa of eq. 4 has two
  negative eigenvalues, the apex tipping sideways; measured with p2-p0 on the coarse mesh,
  positive definite without gravity): its symmetric equilibrium is unstable, and P1's
  artificial stiffness hides it. The static solver still converges to that symmetric state,
  which is what the gravity rows compare, but a model with gravity cannot be linearised
  there for the QPs of calibration and sensing, which assume W_aa positive definite.
  SOFA's Diamond (thicker lower bars) stays stable with p2-p0, but barely: its W_aa
  eigenvalues under gravity are 22, 178, 366 and 374 mm/N (the last two the tipping pair),
  against 2 to 15 mm/N with P1. Whether the real robot tips depends on E, the mass and the
  real geometry; a calibrated E or the nominal model without gravity (the robot file
  allows it) avoids it.

## The reduced model

The reduced p2 models that `make bench` trains on the coarse default mesh
(`softforce model reduce`, docs/reduced_model.md: 200 modes, cables 0-10 mm with gravity),
solved in the same five cases and compared with the same references (`python
benchmarks/study_locking.py --reduced`). The coarse full p2 model of the same robot file is
solved alongside, and the last column compares each reduced model with it:

{reduced}

The five cases are training actuations of the reduced models (gravity alone, each cable at
the box's 10 mm alone), so there a reduced model gives its full model's answer to within
the last column, and against the converged body it inherits the coarse mesh's error, which
the reduction leaves as it is (0.02-0.06 mm more at ECSW 1e-2). The sparser sampling of
ECSW 3e-2 leaves up to 0.18 mm RMS at these edges of the box, one cable pulled 10 mm alone
(0.75 mm before the ECSW weighed its fit in the energy norm, 2026-11-29). The
reduction's own error on untrained loads (other actuations, a contact between features, a
probe, two contacts) is in docs/reduced_model.md.

## What is compared

Each robot is solved to static equilibrium (corotational law, E = 0.18 MPa, nu = 0.45,
0.5 kg, the robot file's gravity) in five load cases: {cases} (a pulled cable alone, the
others held at 0 mm, displacement control). Each model's surface is compared with the
reference at the same material points: for every surface node of the model's mesh that is
not clamped, |u_model - u_reference|, with u_reference the reference's displacement at that
rest point (attached to the reference mesh with the reference's own shape functions). The
tables give the RMS and the maximum over those nodes, and the apex sag under gravity.

**Reference**: P2-P0 on the finest mesh that a few static solves afford
(default robot: gmsh size 4.8 mm, the sample `diamond_fine` mesh, 18k tets, 92k free dofs;
SOFA: its 34k-tet mesh, 164k free dofs; 10 to 45 minutes of solves per model). Plain P2 on
the same mesh is solved too, and the summary also compares the coarse models with P2 and
with the midpoint of the two fields (the best estimate, as they bracket the converged
solution; its uncertainty is about half their 0.44-0.59 mm RMS difference). The P2-P0
sequence between unstructured meshes is not monotonic at the 0.5 mm level (mesh-to-mesh
asymmetries, amplified under gravity by the instability above), so no Richardson
extrapolation is claimed.

## Results

{tables}
![convergence](locking_convergence.png)

## Speed of one FE update on the default robot

K(x), its factorisation (fem/linear_solver.py: CHOLMOD) and the compliance matrices for 51
normal effectors, 4 cables and 2 force points (benchmarks/bench_fem.py `update_timing`),
medians of 5 on this machine (shared, 2 cores: compare ratios):

{speed}
"""


if __name__ == "__main__":
    main()
