"""The ghost table (CONTRACTS 8.4, straylight.analyses.ghost_trace) against independent references.

- A window at normal incidence (incoherent plate, Born & Wolf §7.6.1): the two-reflection ghost carries
  (1 - R)^2 R^2 of the beam, R = ((n - 1)/(n + 1))^2 bare; with a quarter-wave MgF2 layer on each face R is
  the thin-film value ((n0 n_s - n1^2)/(n0 n_s + n1^2))^2 (Macleod, Thin-Film Optical Filters §3.2), written
  here, so the coated ghost is (R_c / R_b)^2 of the bare one.
- The Cooke triplet of the lens-file corpus: C(6, 2) = 15 two-reflection ghosts, each within 4 sigma of
  the engine's analog random walk (branch by probability at every interface, path records grouped by
  their sequence of parts): a different estimator of the same physics.
- The double Gauss ag_dblgauss.seq: C(10, 2) = 45 ghosts.
- The focus estimator on a synthetic bundle converging to a known point.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from engine_helpers import window_scene
from straylight.analyses.ghost_trace import (
    Arrivals, GhostError, _Accumulator, ghost_reflections, ghost_sequence, ghost_table, ghosts, prepare,
)
from straylight.execution import Execution
from straylight.scene import ResolvedScene

LENSES = Path(__file__).resolve().parents[1] / "data" / "lenses"


def _window(coating=None):
    from materials import load_material

    scene, src, mats = window_scene()
    comp = {"type": "dielectric", "n": 1.5}
    if coating:
        comp = {**comp, "coating": coating, "wavelength_nm": 550.0}
    mats = {"glass": load_material({"name": "glass", "components": [comp]})}
    return ResolvedScene(None, scene, mats, (src,), ())


def test_sequences_of_a_four_surface_lens():
    nominal = tuple((p, "T") for p in range(4))
    refl = ghost_reflections(nominal, 2)
    assert len(refl) == 6 and all(a > b for a, b in refl)
    # reflect forward at 2, back through 1, reflect at 0, forward through 1, 2, 3
    assert ghost_sequence(nominal, (2, 0)) == ((0, "T"), (1, "T"), (2, "R"), (1, "T"), (0, "R"), (1, "T"),
                                               (2, "T"), (3, "T"))
    # order 4: r1 > r2 < r3 > r4, counted by hand for 4 sites: sum over (r1, r2) pairs of the pairs after
    four = [r for r in ghost_reflections(nominal, 4) if len(r) == 4]
    brute = [(a, b, c, d) for a in range(4) for b in range(4) for c in range(4) for d in range(4)
             if a > b and c > b and c > d]
    assert sorted(four) == sorted(brute)


def test_window_ghost_is_one_minus_r_squared_r_squared():
    table = ghost_table(prepare(_window()), target_rel_error=0.01)
    R = ((1.5 - 1) / 2.5) ** 2
    assert len(table.rows) == 1
    g = table.rows[0]
    assert g.surfaces == ["bottom", "top"]
    # every ray of a collimated beam at normal incidence has the same weight: the error is ~0
    assert g.power_w == pytest.approx((1 - R) ** 2 * R ** 2, rel=1e-9)
    assert table.nominal.power_w == pytest.approx((1 - R) ** 2, rel=1e-9)
    assert g.focus_mm is None  # a collimated ghost has no waist


def test_coated_window_ghost_is_the_thin_film_reflectance_squared():
    n_s, n1 = 1.5, 1.38
    R_c = ((n_s - n1 ** 2) / (n_s + n1 ** 2)) ** 2  # quarter-wave layer at its design wavelength
    coated = ghost_table(prepare(_window([{"n": n1, "thickness_nm": 550.0 / (4 * n1)}])))
    bare = ghost_table(prepare(_window()))
    R_b = ((n_s - 1) / (n_s + 1)) ** 2
    ratio = coated.rows[0].power_w / bare.rows[0].power_w
    assert ratio == pytest.approx((R_c / R_b) ** 2 * ((1 - R_c) / (1 - R_b)) ** 2, rel=1e-6)


def test_focus_of_a_converging_bundle():
    origin, u, v, a = np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, -1.0])
    acc = _Accumulator((origin, u, v, a, 10.0))
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-3, 3, 500), rng.uniform(-3, 3, 500), np.zeros(500)])
    focus = np.array([0.5, -0.2, -7.0])  # 7 mm beyond the detector along the light's direction (-z)
    d = focus - pts
    d /= np.linalg.norm(d, axis=1)[:, None]
    acc.add(Arrivals(np.ones(500), pts, d, rng.uniform(0.5, 1.5, 500)))
    f, r = acc.geometry()
    assert f == pytest.approx(7.0, abs=1e-9)
    assert 0 < r < 3 * math.sqrt(2)


def _cooke(tmp_path):
    from straylight.cli.main import main

    assert main(["optics", "import", str(LENSES / "optiland" / "cooke_triplet.seq"), "--out", str(tmp_path)]) == 0
    return tmp_path / "scene.toml"


def test_cooke_triplet_has_15_ghosts_each_within_4_sigma_of_the_analog_walk(tmp_path):
    from straylight.analyses.ghosts import specular_sequence
    from straylight.scene import load_scene
    from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions

    rs = load_scene(_cooke(tmp_path))
    table = ghosts(rs, order=2, target_rel_error=0.03)
    assert len(table.rows) == 15
    powers = [r.power_w for r in table.rows]
    assert powers == sorted(powers, reverse=True)
    res = rs.trace(300_000, seed=11, options=TraceOptions(estimator=EstimatorOptions(nee=False),
                                                          output=OutputOptions(record_paths=True, path_depth=40)))
    groups = {g.key: g for g in res.paths.group(by=lambda ev, det: specular_sequence(ev) if det == "image" else None)
              if g.key is not None}
    nominal = groups[tuple(table.nominal.sequence)]
    assert abs(nominal.power_w - table.nominal.power_w) < 4 * math.hypot(nominal.stderr_w, table.nominal.stderr_w)
    z = []
    for r in table.rows:
        g = groups[tuple(r.sequence)]  # every ghost the forced trace lists, the walk finds
        z.append((r.power_w - g.power_w) / math.hypot(r.stderr_w, g.stderr_w))
    assert max(abs(x) for x in z) < 4, z
    assert 0.3 < math.sqrt(np.mean(np.square(z))) < 2.0  # the error bars are neither too small nor too big


def test_double_gauss_has_45_ghosts(tmp_path):
    from straylight.cli.main import main

    assert main(["optics", "import", str(LENSES / "ray-optics" / "ag_dblgauss.seq"), "--out", str(tmp_path)]) == 0
    table = ghosts(tmp_path / "scene.toml", target_rel_error=0.2, max_rays=8192)
    assert len(table.rows) == 45
    assert all(r.power_w > 0 for r in table.rows)


def test_command_writes_the_contract_files(tmp_path):
    from straylight.cli.main import main

    scene = _cooke(tmp_path / "lens")
    out = tmp_path / "g"
    assert main(["ghosts", str(scene), "--order", "2", "--field-deg", "5", "--out", str(out),
                 "--target-rel-error", "0.1"]) == 0
    lines = (out / "ghosts.csv").read_text().splitlines()
    assert lines[0].split(",")[:8] == ["rank", "surfaces", "power_w", "stderr_w", "fraction_of_nominal", "focus_mm",
                                       "radius_mm", "peak_ratio"]
    assert len(lines) == 16
    doc = json.loads((out / "ghosts.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert doc["field_deg"] == 5.0 and doc["order"] == 2 and len(doc["ghosts"]) == 15
    assert (out / "ghosts.png").stat().st_size > 10_000
    page = (out / "view3d.html").read_text()
    assert '"label":"nominal image"' in page
    labels = page.replace("\\u003e", ">")  # the page's JSON escapes ">"
    assert sum(f'"label":"ghost {" > ".join(g["surfaces"])}"' in labels for g in doc["ghosts"][:12]) >= 10  # the strongest ghosts are selectable paths of the view


def test_the_view_draws_each_ghost_along_its_own_sequence(tmp_path):
    from straylight.analyses.ghost_trace import sample_polylines

    table = ghosts(_cooke(tmp_path), target_rel_error=0.2)
    opt = table.optics
    det = opt.surfaces[opt.detector]
    g = table.rows[0]
    lines = sample_polylines(opt, g.parts, n_paths=4)
    assert len(lines) == 4
    for pts in lines:
        assert len(pts) == len(g.parts) + 2  # the source, every forced hit, the detector
        assert abs(float(np.dot(pts[-1] - det.vertex_mm, det.axis))) < 1e-6  # ends on the detector's plane
        # after the two reflections the ray runs backward (-z) between them, forward (+z) elsewhere
        dz = np.diff(pts[:, 2])
        assert (dz < 0).sum() >= 1 and dz[-1] > 0


@pytest.mark.parametrize("args, words", [(["--order", "3"], "even"), (["--field-deg", "95"], "field"),
                                         (["--max-seconds", "0"], "--max-seconds"), (["--workers", "0"], "--workers"),
                                         (["--workers", "100000"], "--workers")])
def test_bad_requests_are_one_line_errors(tmp_path, capsys, args, words):
    from straylight.cli.main import main

    scene = _cooke(tmp_path / "lens")
    capsys.readouterr()
    assert main(["ghosts", str(scene), "--out", str(tmp_path / "g"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


def test_a_scene_without_a_detector_is_refused():
    scene, src, mats = window_scene()
    from geometry.mesh import Scene

    no_det = ResolvedScene(None, Scene(tuple(p for p in scene.parts if p.role != "detector")), mats, (src,), ())
    with pytest.raises(GhostError, match="no detector"):
        prepare(no_det)


def test_the_nominal_path_crosses_every_surface_not_the_light_around_the_lenses(tmp_path):
    """A lens file has no barrel: in the Canon EF 28 mm f/2.8 (OpticsDatabase), light entering the large front
    elements outside the small rear ones goes around them to the image, more power than the focused design
    path. The nominal sequence is the design path, through all 16 refracting surfaces in order."""
    from straylight.analyses.ghost_trace import nominal_sequence
    from straylight.cli.main import main
    from straylight.scene import load_scene

    lens = LENSES / "OpticsDatabase" / "Canon_EF28mm_f2.8_IS_USM.zmx"
    assert main(["optics", "import", str(lens), "--out", str(tmp_path)]) == 0
    opt = prepare(load_scene(tmp_path / "scene.toml"))
    nominal = nominal_sequence(opt)
    names = [opt.names[p] for p, _ in nominal]
    refracting = [f"s{i}" for i in range(2, 19) if i != 11]  # s11 is the stop (air on both sides)
    assert names == refracting and all(a == "T" for _, a in nominal)


@pytest.mark.parametrize("lens", ["optiland/mirror.seq", "ray-optics/US08011793-1.zmx"])
def test_a_mirror_system_is_refused_as_one_with_no_ghost(tmp_path, capsys, lens):
    """optiland's mirror.seq (one concave mirror) and the four-mirror US08011793-1 (whose beam, off axis in the
    design, misses the image on axis): no lens or window, so no ghost; the refusal says so rather than that no
    light arrives."""
    from straylight.cli.main import main

    assert main(["optics", "import", str(LENSES / lens), "--out", str(tmp_path / "lens")]) == 0
    capsys.readouterr()
    assert main(["ghosts", str(tmp_path / "lens" / "scene.toml"), "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mirror system" in err[0] and "no ghost" in err[0], err


def test_light_leaves_a_flat_surface_far_from_the_origin(tmp_path):
    """ray-optics' schmidt.seq: corrector, mirror, then a field flattener whose last face is flat, 75 mm from
    the origin, 1.7 mm before the image. There a float32 ulp is 7.6e-6 mm: a ray offset off the flat face by
    less meets its facet again at t = 0 and never reaches the image. The design path crosses all five surfaces."""
    from straylight.analyses.ghost_trace import nominal_sequence
    from straylight.cli.main import main
    from straylight.scene import load_scene

    assert main(["optics", "import", str(LENSES / "ray-optics" / "schmidt.seq"), "--out", str(tmp_path)]) == 0
    opt = prepare(load_scene(tmp_path / "scene.toml"))
    nominal = nominal_sequence(opt)
    assert [(opt.names[p], a) for p, a in nominal] == [("s1", "T"), ("s2", "T"), ("s3", "R"), ("s4", "T"),
                                                       ("s5", "T")]
    assert len(ghost_reflections(nominal, 2)) == 6  # C(4, 2): the four refracting surfaces


def test_the_ghosts_share_a_ray_budget_and_say_when_it_stops_them(tmp_path):
    """A 16-surface lens has 120 ghosts; to 2 % each they take minutes, so the table has a total ray budget,
    shared by water-filling. Under a budget large enough for every ghost the table is the one traced without
    it, ray for ray (each ghost continues its own random stream); under a small one every ghost is still
    listed, with the error it reached, and the table says how many the budget stopped."""
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    free = ghost_table(opt, target_rel_error=0.05, max_total_rays=10 ** 9, batch_rays=4096)
    assert not free.notes
    need = sum(r.rays for r in free.rows)
    shared = ghost_table(opt, target_rel_error=0.05, max_total_rays=need, batch_rays=4096)  # < an equal share each
    assert not shared.notes
    assert [(r.surfaces, r.power_w, r.stderr_w, r.rays) for r in shared.rows] == \
        [(r.surfaces, r.power_w, r.stderr_w, r.rays) for r in free.rows]
    small = ghost_table(opt, target_rel_error=0.001, max_total_rays=15 * 4096)
    assert len(small.rows) == 15 and small.notes and small.notes[0].startswith("15 of 15 ghosts")
    # two batches each would be twice the budget: the batches are halved, and the table keeps to its budget
    assert all(r.rays == 2 * 2048 and 0 < r.stderr_w < r.power_w for r in small.rows)
    assert sum(r.rays for r in small.rows) == 15 * 4096


def test_an_image_turned_off_the_detector_is_refused_with_the_way_out(tmp_path, capsys):
    """Edmund 32-299 (OpticsDatabase), a 12.5 mm achromat imported for its on-axis field: its detector is a
    0.375 mm disk, and at 5 deg the image lies 1.1 mm off axis. The one-line refusal says to import the lens
    at that field; so imported, its ghost table is found."""
    from straylight.cli.main import main

    lens = LENSES / "OpticsDatabase" / "Edmund_32-299.zmx"
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "lens")]) == 0
    capsys.readouterr()
    assert main(["ghosts", str(tmp_path / "lens" / "scene.toml"), "--field-deg", "5", "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "optics import --field-deg 5" in err[0] and "radius 0.375 mm" in err[0], err
    assert main(["optics", "import", str(lens), "--field-deg", "5", "--out", str(tmp_path / "lens5")]) == 0
    assert len(ghosts(tmp_path / "lens5" / "scene.toml", target_rel_error=0.2).rows) == 3


def test_a_nominal_path_with_no_light_is_refused_in_one_line(tmp_path, capsys):
    """ray-optics' lens_reflection_test.seq, whose image surface sits in the incoming beam: the design path
    found by the likelier branch carries no light when traced as a forced sequence. The table had every
    ghost's fraction of the nominal image and peak ratio null (exit 0); now one line and exit 2."""
    from straylight.cli.main import main

    assert main(["optics", "import", str(LENSES / "ray-optics" / "lens_reflection_test.seq"),
                 "--out", str(tmp_path / "lens")]) == 0
    capsys.readouterr()
    assert main(["ghosts", str(tmp_path / "lens" / "scene.toml"), "--max-seconds", "5",
                 "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no light reaches the detector" in err[0] and "nominal path" in err[0], err
    assert not (tmp_path / "g" / "ghosts.json").exists()


def test_the_double_gauss_design_path_carries_what_the_analog_walk_finds(tmp_path):
    """The design path's power through the double Gauss ag_dblgauss.seq, forced-sequence against the engine's
    analog walk (path records grouped by sequence): rays offset off a surface by less than the intersector's
    float32 resolution were lost on its flat-ish faces 40-90 mm from the origin (0.272 W against 0.377)."""
    from straylight.analyses.ghost_trace import nominal_sequence, trace_sequence
    from straylight.analyses.ghosts import specular_sequence
    from straylight.cli.main import main
    from straylight.scene import load_scene
    from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions

    assert main(["optics", "import", str(LENSES / "ray-optics" / "ag_dblgauss.seq"), "--out", str(tmp_path)]) == 0
    rs = load_scene(tmp_path / "scene.toml")
    opt = prepare(rs)
    nominal = nominal_sequence(opt)
    per_ray = trace_sequence(opt, nominal, 20_000, np.random.default_rng(5)).per_ray_w * 20_000
    forced, forced_err = per_ray.mean(), per_ray.std(ddof=1) / math.sqrt(len(per_ray))
    res = rs.trace(40_000, seed=7, options=TraceOptions(estimator=EstimatorOptions(nee=False),
                                                        output=OutputOptions(record_paths=True, path_depth=40)))
    groups = {g.key: g for g in res.paths.group(by=lambda ev, det: specular_sequence(ev) if det == "image" else None)
              if g.key is not None}
    walk = groups[tuple(opt.names[p] for p, _ in nominal)]
    assert abs(forced - walk.power_w) < 4 * math.hypot(forced_err, walk.stderr_w), (forced, walk.power_w)


def test_two_ghosts_with_one_label_keep_their_own_maps(tmp_path):
    """A part the design path crosses twice (a Mangin mirror's glass, met going in and coming out) gives two
    ghosts the same surface names. Here the Cooke triplet's s2 is renamed s1 so that s3 > s1 and s3 > s2 share
    a label: every ghost keeps its own irradiance map (ghosts.png draws each from its own), none overwritten."""
    import dataclasses

    from straylight.analyses.ghost_trace import plot_maps
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    names = list(opt.names)
    names[names.index("s2")] = "s1"
    table = ghost_table(dataclasses.replace(opt, names=tuple(names)), target_rel_error=0.2)
    assert len(table.rows) == 15 and len(table.maps) == 16  # the nominal image's and one per ghost
    keys = [r.map_key for r in table.rows]
    assert len(set(keys)) == 15 and sum(" > ".join(r.surfaces) == "s3 > s1" for r in table.rows) == 2
    assert all("map_key" not in d for d in table.to_json_dict()["ghosts"])
    plot_maps(table, tmp_path / "ghosts.png", top=15)


def test_ghosts_stopped_by_the_per_ghost_cap_are_counted_in_the_notes(tmp_path):
    """A ghost that reaches --max-rays above the target error (a thin bundle few rays find, as in ACL3026U.zmx)
    keeps its error, and the table says how many did; without a cap that bites, no such note."""
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    capped = ghost_table(opt, target_rel_error=0.001, max_rays=8192)
    assert any(n.startswith("15 of 15 ghosts reached --max-rays (8192 rays each)") for n in capped.notes), capped.notes
    assert not ghost_table(opt, target_rel_error=0.2, max_rays=8192).notes


def test_a_ghost_no_ray_reaches_says_how_small_it_is(tmp_path):
    """ray-optics' questar35.seq: its one ghost's beam lands on the stop annulus after the secondary, so no ray
    of it reaches the image. Listed as 0 +- 0, it also carries the 95 % bound that many empty rays give
    (3 x the source's power / its rays: each ray carries at most the source's power / rays), and the notes
    and ghosts.md say so; ghosts.json stays strict JSON (upper_w is null where rays arrived)."""
    from straylight.analyses.ghost_trace import write_table
    from straylight.cli.main import main
    from straylight.scene import load_scene

    assert main(["optics", "import", str(LENSES / "ray-optics" / "questar35.seq"), "--out", str(tmp_path)]) == 0
    rs = load_scene(tmp_path / "scene.toml")
    table = ghosts(rs, order=2)
    dark = [r for r in table.rows if r.power_w == 0.0]
    assert dark and all(r.stderr_w == 0.0 for r in dark)
    for r in dark:
        assert r.upper_w == pytest.approx(3.0 * rs.sources[0].power_w / r.rays)
    assert table.nominal.upper_w is None and all(r.upper_w is None for r in table.rows if r.power_w > 0)
    assert any("had no ray reach the detector" in note for note in table.notes)
    write_table(table, tmp_path / "g")
    doc = json.loads((tmp_path / "g" / "ghosts.json").read_text(),
                     parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert doc["ghosts"][-1]["upper_w"] == pytest.approx(dark[-1].upper_w)
    assert "at 95 %: no ray arrived" in (tmp_path / "g" / "ghosts.md").read_text()


def test_ghosts_drawn_where_their_rays_arrive_agree_with_uniform_rays_and_need_fewer(tmp_path):
    """A ghost whose first rays mostly miss the stop draws the rest from where those arrived, each carrying 1 / p:
    the same powers as uniform rays (each of the Cooke triplet's ghosts within 4 sigma), for fewer rays."""
    from straylight.analyses.ghost_trace import prepare
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    guided = ghost_table(opt, order=2, target_rel_error=0.02)
    uniform = ghost_table(opt, order=2, target_rel_error=0.02, guide_below=0.0)
    assert not any("were aimed at that part" in n for n in uniform.notes)
    drawn = [int(n.split()[0]) for n in guided.notes if "were aimed at that part" in n]
    assert drawn and drawn[0] >= 5, guided.notes  # the triplet's stop passes 2-4 % of the disk to several ghosts
    by_label = {r.map_key: r for r in uniform.rows}
    z = [(r.power_w - by_label[r.map_key].power_w) / math.hypot(r.stderr_w, by_label[r.map_key].stderr_w)
         for r in guided.rows]
    assert max(abs(x) for x in z) < 4, z
    assert 0.3 < math.sqrt(np.mean(np.square(z))) < 2.0
    assert sum(r.rays for r in guided.rows) < 0.8 * sum(r.rays for r in uniform.rows)
    rel = [sorted(r.stderr_w / r.power_w for r in t.rows) for t in (guided, uniform)]
    assert rel[0][len(rel[0]) // 2] <= rel[1][len(rel[1]) // 2]


def test_the_design_path_of_a_fisheye_with_a_tiny_pupil_is_found(tmp_path):
    """The Kinoptik Super-Tegea 1.9 mm fisheye: a 1 mm entrance pupil behind a 93 mm front element, so 1e-4 of
    the source's rays take the design path; 4000 rays showed none ("no source ray reaches the detector"). The
    search looks again with more rays until 20 arrive: the path crosses every lens surface, in order."""
    from straylight.analyses.ghost_trace import nominal_sequence
    from straylight.cli.main import main
    from straylight.scene import load_scene

    lens = LENSES / "OpticsDatabase" / "Kinoptik_Super-Tegea_1.9mm_f1.9_Fisheye.zmx"
    assert main(["optics", "import", str(lens), "--out", str(tmp_path)]) == 0
    opt = prepare(load_scene(tmp_path / "scene.toml"))
    nominal = nominal_sequence(opt)
    assert [opt.names[p] for p, _ in nominal] == [f"s{i}" for i in range(1, 16) if i != 7]  # s7: the stop, air/air
    assert all(act == "T" for _, act in nominal)


def test_a_ghost_whose_budget_ends_as_it_learns_keeps_its_uniform_rays(tmp_path):
    """Under a budget of two batches a ghost, a ghost that learns its table after them has no rays left to draw from
    it: its row is its uniform rays' estimate (rays as traced, positive power with an error), and the notes do not
    count it among the ghosts drawn from a table."""
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    table = ghost_table(opt, target_rel_error=0.001, max_total_rays=15 * 2 * 1024)
    assert not any("were aimed at that part" in n for n in table.notes), table.notes
    assert all(r.rays == 2 * 1024 and 0 < r.stderr_w < r.power_w for r in table.rows)
    assert sum(r.rays for r in table.rows) == 15 * 2048


def _fake_clock(monkeypatch, s_per_ray_part=1e-6):
    """A monotonic clock that moves only as rays are traced: each forced batch of n rays through a k-part sequence
    takes n k ``s_per_ray_part`` seconds, the nominal image's too (the cap's estimate of a ghost's cost). No test
    here waits on the machine's clock."""
    from straylight.analyses import ghost_trace

    now = [0.0]
    real = ghost_trace.trace_sequence

    def timed(opt, seq, n, rng, table=None):
        now[0] += n * len(seq) * s_per_ray_part
        return real(opt, seq, n, rng, table)

    monkeypatch.setattr(ghost_trace, "trace_sequence", timed)
    monkeypatch.setattr(ghost_trace, "monotonic", lambda: now[0])
    return now


def _first_round_s(opt, batch, s_per_ray_part=1e-6):
    """Seconds one batch of every order-2 ghost takes on the fake clock."""
    from straylight.analyses.ghost_trace import nominal_sequence

    nominal = nominal_sequence(opt)
    return sum(len(ghost_sequence(nominal, r)) for r in ghost_reflections(nominal, 2)) * batch * s_per_ray_part


def test_a_time_cap_leaves_every_ghost_its_estimate_and_says_how_far_it_got(tmp_path, monkeypatch):
    """--max-seconds: every ghost gets its first batch before any ghost its next, so the cap stops all of them
    alike, each keeping the estimate it reached (the budget's way). Here one 4096-ray batch each would take the
    whole cap: the first ghost's batch, timed, shows it, and the 14 after it get the largest common batch that
    ends the first round within half the cap; the second round fills the other half. The warnings say how many
    ghosts the cap stopped, and at what worst error."""
    from straylight.analyses.ghost_trace import ghost_priors, nominal_sequence
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    nominal = nominal_sequence(opt)
    refls = ghost_reflections(nominal, 2)
    priors = dict(zip(refls, ghost_priors(opt, nominal, refls)))  # the order the first batches go out in
    _fake_clock(monkeypatch)
    cap_s = _first_round_s(opt, 4096)
    table = ghost_table(opt, target_rel_error=0.001, max_seconds=cap_s)
    rows = sorted(table.rows, key=lambda r: (-priors[tuple(r.reflections)], refls.index(tuple(r.reflections))))
    first, rest = rows[0], rows[1:]
    parts_rest = sum(len(r.parts) for r in rest)
    half_s = 0.5 * cap_s / 1e-6  # in rays x parts on the fake clock
    b = int((half_s - 4096 * len(first.parts)) / parts_rest)
    assert (4096 * len(first.parts) + b * parts_rest) <= half_s < (4096 * len(first.parts) + (b + 1) * parts_rest)
    assert 256 <= b < 4096
    assert first.rays % 4096 == 0 and all(r.rays % b == 0 for r in rest), ([r.rays for r in rows], b)
    rounds = [first.rays // 4096] + [r.rays // b for r in rest]
    assert min(rounds) >= 1 and max(rounds) - min(rounds) <= 1, rounds  # each ghost one batch a round
    assert sorted(rounds)[1] == 2, rounds  # the second half of the cap: a second round (less a batch's rounding)
    assert all(r.power_w > 0 and 0 < r.stderr_w < r.power_w for r in table.rows)
    worst = max(r.stderr_w / r.power_w for r in table.rows)
    assert len(table.warnings) == 1 and table.warnings[0] in table.notes, table.warnings
    assert table.warnings[0].startswith(f"15 of 15 ghosts were stopped by the time cap (--max-seconds {cap_s:g})")
    assert f"at up to {worst:.1%} relative error" in table.warnings[0]
    assert "ray budget" not in " ".join(table.notes)


def test_a_cap_generous_enough_changes_nothing(tmp_path, monkeypatch):
    """Traced one batch a ghost per round under the cap, each ghost on its own random stream: a cap that does not
    bite gives the table traced without it, ray for ray, and no warning."""
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    free = ghost_table(opt, target_rel_error=0.05)
    _fake_clock(monkeypatch)
    capped = ghost_table(opt, target_rel_error=0.05, max_seconds=10 * _first_round_s(opt, 4096))
    assert [(r.surfaces, r.power_w, r.stderr_w, r.rays) for r in capped.rows] == \
        [(r.surfaces, r.power_w, r.stderr_w, r.rays) for r in free.rows]
    assert not capped.warnings and capped.notes == free.notes


def test_ghosts_the_cap_left_untraced_have_no_estimate(tmp_path, monkeypatch):
    """With its batches fixed (batch_rays given: no shrink), a cap shorter than one batch each leaves ghosts
    untraced: those are listed last with no power, error or fraction (None; null in ghosts.json, empty in
    ghosts.csv, "not traced" in ghosts.md), never as a measured 0, and a warning says how many."""
    from straylight.analyses.ghost_trace import write_table
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    _fake_clock(monkeypatch)
    table = ghost_table(opt, target_rel_error=0.001, batch_rays=4096, max_seconds=0.3 * _first_round_s(opt, 4096))
    traced = [r for r in table.rows if r.rays]
    untraced = [r for r in table.rows if not r.rays]
    assert traced and untraced and table.rows == traced + untraced
    assert all(r.rays == 4096 and r.power_w > 0 for r in traced)
    assert all(r.power_w is None and r.stderr_w is None and r.fraction_of_nominal is None and r.upper_w is None
               for r in untraced)
    assert any(w.startswith(f"{len(untraced)} of 15 ghosts were not traced before the time cap") for w in table.warnings)
    assert any(w.startswith(f"{len(traced)} of 15 ghosts were stopped by the time cap") for w in table.warnings)
    write_table(table, tmp_path / "g")
    doc = json.loads((tmp_path / "g" / "ghosts.json").read_text(),
                     parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    last = doc["ghosts"][-1]
    assert last["power_w"] is None and last["stderr_w"] is None and last["fraction_of_nominal"] is None
    assert last["rays"] == 0
    rows = (tmp_path / "g" / "ghosts.csv").read_text().splitlines()
    cells = rows[-1].split(",")
    assert cells[2:5] == ["", "", ""] and cells[8] == "0"
    assert "| not traced (time cap) |" in (tmp_path / "g" / "ghosts.md").read_text()


def test_the_command_warns_of_what_to_act_on_and_notes_the_rest(tmp_path, monkeypatch, capsys):
    """`ghosts --max-seconds S`: a cap that stops ghosts is a warning, one `straylight: warning:` line each; how
    the table was traced (ghosts aimed at the part of the beam that gets through) is a note in ghosts.md and the
    printed table, never on stderr."""
    from straylight.cli.main import main

    scene = _cooke(tmp_path / "lens")
    capsys.readouterr()
    out = tmp_path / "g"
    assert main(["ghosts", str(scene), "--out", str(out), "--no-view3d"]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err, captured.err  # the Cooke triplet to 2 %: nothing to act on
    md = (out / "ghosts.md").read_text()
    assert "Note: " in md and "were aimed at that part" in md and "Warning:" not in md
    assert "were aimed at that part" in captured.out
    notes = json.loads((out / "ghosts.json").read_text())["notes"]
    assert len(notes) == 1 and "were aimed at that part" in notes[0]

    _fake_clock(monkeypatch)  # moved by the rays this process traces: one worker, this one
    assert main(["ghosts", str(scene), "--out", str(out), "--no-view3d", "--target-rel-error", "0.001",
                 "--max-seconds", "0.5", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert err and all(line.startswith("straylight: warning: ") for line in err), err
    assert any("were stopped by the time cap (--max-seconds 0.5)" in line for line in err), err
    assert not any("aimed" in line for line in err), err
    md = (out / "ghosts.md").read_text()
    assert "Warning: " in md and "time cap" in md
    assert "Warning:" not in captured.out  # printed once, on stderr
    doc = json.loads((out / "ghosts.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert any("time cap" in n for n in doc["notes"])


def _row_numbers(table):
    return [(r.surfaces, r.reflections, r.power_w, r.stderr_w, r.fraction_of_nominal, r.focus_mm, r.radius_mm,
             r.peak_ratio, r.rays, r.upper_w) for r in table.rows]


def test_the_table_is_the_same_on_any_number_of_workers(tmp_path, monkeypatch):
    """workers=K: each round's ghosts are traced in K forked processes, a ghost's state (random stream, sums,
    learnt table) going out and coming back whole; without a time cap the table is the one process's, number for
    number, maps included, also over a water-filling round (a budget whose equal first shares stop some ghosts)."""
    from straylight.analyses import ghost_trace
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    rounds = []
    real_round = ghost_trace._Pool.round
    monkeypatch.setattr(ghost_trace._Pool, "round", lambda self, todo, *a: (rounds.append(len(todo)),
                                                                            real_round(self, todo, *a))[1])
    kwargs = dict(target_rel_error=0.03, max_total_rays=15 * 4 * 4096)  # first shares: 4 batches
    one = ghost_table(opt, execution=Execution(workers=1), **kwargs)
    assert not rounds  # one process: no pool
    two = ghost_table(opt, execution=Execution(workers=2), **kwargs)
    assert len(rounds) >= 2 and rounds[0] == 15, rounds  # the pool traced the first round and water-filling ones
    assert _row_numbers(two) == _row_numbers(one)
    assert two.notes == one.notes and two.nominal.power_w == one.nominal.power_w
    assert two.maps.keys() == one.maps.keys() and all(np.array_equal(two.maps[k], one.maps[k]) for k in one.maps)
    assert max(r.rays for r in one.rows) > 4 * 4096 > min(r.rays for r in one.rows)  # (a second round)


def test_a_time_cap_on_workers_gives_every_ghost_one_batch_before_any_its_second(tmp_path):
    """Under --max-seconds with workers, a round ends when its last ghost is back and the next starts after it:
    whatever the cap, the ghosts' batch counts differ by at most one, and ghosts are left untraced only where none
    has a second batch. (The machine's own clock: the counts vary from run to run, the rule does not.)"""
    import time

    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    t = time.perf_counter()
    ghost_table(opt, target_rel_error=0.5, batch_rays=1024, execution=Execution(workers=1))
    one_round_s = time.perf_counter() - t  # the nominal image's trace and about two rounds of ghosts
    for cap_s in (0.5 * one_round_s, 2.5 * one_round_s):
        table = ghost_table(opt, target_rel_error=0.0001, min_fraction=0.0, batch_rays=1024, execution=Execution(workers=2),
                            max_seconds=cap_s)
        assert all(r.rays % 1024 == 0 for r in table.rows)
        batches = [r.rays // 1024 for r in table.rows]
        assert max(batches) - min(batches) <= 1, (cap_s, batches)
        assert max(batches) >= 1 and table.warnings, (cap_s, batches)


def _two_windows():
    """Two windows in one collimated beam (n = 1.5, normal incidence, light toward -z): "a" first, its faces with a
    quarter-wave layer of n = 1.25 (R = ((1.5 - 1.25^2) / (1.5 + 1.25^2))^2 = 4.2e-4, Macleod 3.2), "b" after it
    bare (R = 0.04). In surface order the ghost between a's faces comes first and b's (a hundred times R squared
    brighter: 1e4 times) last."""
    from geometry.analytic import Plane, analytic_part
    from geometry.mesh import Scene
    from materials import load_material
    from straylight.sources import CollimatedDisk

    up = np.array([0.0, 0.0, 1.0])
    coat = [{"n": 1.25, "thickness_nm": 550.0 / (4 * 1.25)}]
    mats = {"coated": load_material({"name": "coated", "components": [{"type": "dielectric", "n": 1.5,
                                                                       "coating": coat, "wavelength_nm": 550.0}]}),
            "bare": load_material({"name": "bare", "components": [{"type": "dielectric", "n": 1.5}]})}
    parts = [analytic_part(name, Plane(np.array([0, 0, z]), sign * up, math.inf, 0.0, 100.0, 0.0), mat)
             for name, z, sign, mat in (("a_top", 40.0, 1, "coated"), ("a_bottom", 30.0, -1, "coated"),
                                        ("b_top", 10.0, 1, "bare"), ("b_bottom", 0.0, -1, "bare"))]
    parts.append(analytic_part("det", Plane(np.array([0, 0, -20.0]), up, math.inf, 0.0, 300.0, 0.0), None,
                               "detector"))
    src = CollimatedDisk(center_mm=np.array([0, 0, 60.0]), normal=-up, direction=-up, radius_mm=5.0)
    return ResolvedScene(None, Scene(tuple(parts)), mats, (src,), ())


def test_a_capped_run_traces_the_likely_brightest_ghost_first(tmp_path, monkeypatch):
    """Under --max-seconds the first batches go out by a prior (each ghost's normal-incidence reflectances and
    transmittances along its sequence, coatings included), not in surface order: a cap that lets one ghost's batch
    out traces the bare window's ghost, which surface order lists last, and leaves the coated one's untraced. The
    order of the first batches is the priors' (bare pair, then the mixed ones, coated pair last)."""
    from straylight.analyses import ghost_trace

    opt = prepare(_two_windows())
    nominal = ghost_trace.nominal_sequence(opt)
    assert [opt.names[p] for p, _ in nominal] == ["a_top", "a_bottom", "b_top", "b_bottom"]
    R_c = ((1.5 - 1.25 ** 2) / (1.5 + 1.25 ** 2)) ** 2
    assert ghost_trace.normal_incidence_powers(opt, nominal[0][0])[0] == pytest.approx(R_c, rel=1e-9)
    assert ghost_trace.normal_incidence_powers(opt, nominal[2][0])[0] == pytest.approx(0.04, rel=1e-9)
    traced = []
    now = _fake_clock(monkeypatch)
    real = ghost_trace.trace_sequence  # (the fake clock's)

    def seen(opt_, seq, n, rng, table=None):
        traced.append(tuple(opt.names[p] for p, act in seq if act == "R"))
        return real(opt_, seq, n, rng, table)

    monkeypatch.setattr(ghost_trace, "trace_sequence", seen)
    generous = ghost_table(opt, target_rel_error=0.001, batch_rays=1024, max_seconds=1e9, max_total_rays=6 * 1024)
    firsts = list(dict.fromkeys(t for t in traced if t))  # the ghosts (reflecting somewhere) as first traced
    assert firsts[0] == ("b_bottom", "b_top") and firsts[-1] == ("a_bottom", "a_top"), firsts
    assert [r.surfaces for r in generous.rows][0] == ["b_bottom", "b_top"]  # (the table: by power, as always)
    now[0] = 0.0
    traced.clear()
    one_batch_s = 1024 * len(ghost_trace.ghost_sequence(nominal, (3, 2))) * 1e-6  # the fake clock's
    table = ghost_table(opt, target_rel_error=0.001, batch_rays=1024, max_seconds=0.5 * one_batch_s)
    done = [r for r in table.rows if r.rays]
    assert [r.surfaces for r in done] == [["b_bottom", "b_top"]], [(r.surfaces, r.rays) for r in table.rows]
    assert table.rows[-1].power_w is None and len(table.rows) == 6


def _plain_next_hits(opt, b, casts=None):
    """next_hits as first written (index arrays for every group of rays, every ray copied): the reference its
    shortcuts must match bit for bit; ``casts`` gets the number of casts (> 1: some ray was passed through)."""
    from straylight.analyses.ghost_trace import SELF_HIT_MM

    def dot(a, c):
        return np.einsum("ij,ij->i", a, c)

    n = len(b.w)
    part, point, facing, front = np.full(n, -1, np.int64), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, bool)
    todo, o, last = np.arange(n), b.o.copy(), b.last.copy()
    for cast in range(4):
        if len(todo) == 0:
            break
        if casts is not None:
            casts.append(cast + 1)
        tri, t = opt.isect.intersect(o[todo], b.d[todo])
        tri, t = np.asarray(tri, np.int64), np.asarray(t, float)
        hit_part = np.where(tri >= 0, opt.tri_part[np.maximum(tri, 0)], -1)
        retry = []
        for p in np.unique(hit_part[hit_part >= 0]):
            g = np.flatnonzero(hit_part == p)
            rows = todo[g]
            tr, n_front, ok = opt.surfaces[p].refine_hits(o[rows], b.d[rows], t[g])
            accept = ok & ~((last[rows] == p) & (tr < SELF_HIT_MM))
            r = rows[accept]
            part[r] = p
            point[r] = o[r] + tr[accept, None] * b.d[r]
            fr = dot(b.d[r], n_front[accept]) < 0
            front[r] = fr
            facing[r] = np.where(fr[:, None], n_front[accept], -n_front[accept])
            again = rows[~accept]
            o[again] = o[again] + (t[g][~accept] + opt.eps_mm)[:, None] * b.d[again]
            last[again] = p
            retry.append(again)
        todo = np.concatenate(retry) if retry else np.zeros(0, np.int64)
    return part, dot(point - b.o, b.d), point, facing, front


def test_the_whole_bundle_shortcuts_give_the_plain_numbers(tmp_path):
    """A forced step takes the bundle whole where it can (every ray cast hits one part, or every ray of a part is
    accepted: no index arrays; one branch for all: only its direction computed). Bit for bit the numbers of the
    plain way (:func:`_plain_next_hits`, the per-ray branch mask), along every ghost of the Cooke triplet, whose
    steps take each way (all rays on one part and accepted, some passed through, some elsewhere)."""
    from straylight.analyses.ghost_trace import emit, fresnel, interact, next_hits, nominal_sequence
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    nominal = nominal_sequence(opt)
    kinds = set()
    for k, refl in enumerate(ghost_reflections(nominal, 2)):
        b = emit(opt, 1000, np.random.default_rng(k))
        for p, act in ghost_sequence(nominal, refl):
            hits = next_hits(opt, b)
            casts: list = []
            for fast, plain in zip(hits, _plain_next_hits(opt, b, casts)):
                assert np.array_equal(fast, plain), (refl, p)
            part, dist, point, facing, front = hits
            kinds.add((bool((part == part[0]).all()), max(casts) > 1))
            ok = np.flatnonzero(part == p)
            b = b.take(ok)
            part, dist, point, facing, front = part[ok], dist[ok], point[ok], facing[ok], front[ok]
            co = fresnel(opt, part, front, np.clip(-np.einsum("ij,ij->i", b.d, facing), 0.0, 1.0), dist)
            b.last = part
            one = interact(b, point, facing, co, act == "R", opt.eps_mm)
            each = interact(b, point, facing, co, np.full(len(ok), act == "R"), opt.eps_mm)
            for f in ("o", "d", "w", "S", "e1", "last"):
                assert np.array_equal(getattr(one, f), getattr(each, f)), (refl, p, act, f)
            b = one
    assert kinds == {(True, False), (False, False), (True, True), (False, True)}, kinds


def test_a_cap_counted_from_the_start_bounds_the_nominal_trace_and_the_writing_too(tmp_path, monkeypatch):
    """``started`` (the command line's start, the notebook call's): the cap bounds the whole call, the nominal
    image's trace included, and the ghosts stop ``reserve_s`` early (the command's time to write its files). On the
    fake clock the last batch is dispatched before ``started + cap - reserve`` and ends within one batch of it,
    where the same cap counted after the nominal trace (``started`` None) runs a nominal trace's time longer. A
    start so long ago that the deadline is past before the first ghost still leaves the ghosts
    ``MIN_GHOST_SHARE`` of the cap: every ghost gets its first rays."""
    from straylight.analyses.ghost_trace import MIN_GHOST_SHARE, nominal_sequence
    from straylight.scene import load_scene

    opt = prepare(load_scene(_cooke(tmp_path)))
    now = _fake_clock(monkeypatch)
    nominal_rays = ghost_table(opt, target_rel_error=1e-3, max_seconds=1e-9).nominal.rays  # (the same each call)
    nominal_s = nominal_rays * len(nominal_sequence(opt)) * 1e-6
    cap_s, reserve_s = nominal_s + 3 * _first_round_s(opt, 4096), 0.5 * _first_round_s(opt, 4096)
    longest_batch_s = 4096 * max(len(ghost_sequence(nominal_sequence(opt), r))
                                 for r in ghost_reflections(nominal_sequence(opt), 2)) * 1e-6
    now[0] = 0.0
    after_nominal = ghost_table(opt, target_rel_error=1e-3, max_seconds=cap_s)
    end_after_nominal = now[0]
    now[0] = 0.0
    whole = ghost_table(opt, target_rel_error=1e-3, max_seconds=cap_s, started=0.0, reserve_s=reserve_s)
    end_whole = now[0]
    assert whole.nominal.rays == after_nominal.nominal.rays == nominal_rays >= 2 * 4096
    assert cap_s - reserve_s <= end_whole <= cap_s - reserve_s + longest_batch_s, (end_whole, cap_s, reserve_s)
    assert cap_s + nominal_s <= end_after_nominal <= cap_s + nominal_s + longest_batch_s
    assert sum(r.rays for r in whole.rows) < sum(r.rays for r in after_nominal.rows)
    now[0] = 0.0
    late = ghost_table(opt, target_rel_error=1e-3, max_seconds=cap_s, started=-1e6)
    assert all(r.rays > 0 for r in late.rows)  # the ghosts still had MIN_GHOST_SHARE of the cap
    assert nominal_s + MIN_GHOST_SHARE * cap_s <= now[0] <= nominal_s + MIN_GHOST_SHARE * cap_s + longest_batch_s


SINGLET_SEQ = """TITLE 'equiconvex singlet'
EPD 4.0
WL 587.6
REF 1
YAN 0.0 1.0
SO 0.0 1e10
S  60.0 6.0  N-BK7_SCHOTT
  STO
S  -60.0 57.0436
SI 0.0 0.0
"""


def _paraxial_ghost(surfaces, j, i, h=1e-4, heights=None):
    """A two-reflection ghost (reflected at surface ``j``, then at ``i`` < ``j``) of a prescription.json surface
    list by a paraxial y-nu trace (Welford, Aberrations of Optical Systems, 2.4: refraction nu' = nu - y (n' - n) c,
    transfer y' = y + (d / n) nu; a reflection is a refraction into -n, the path back counted with -d in -n, so
    d / n keeps its sign), from a ray parallel to the axis at height ``h``: (y, u) leaving the last surface;
    ``heights`` (a list) gets (surface, y) at every surface the ghost meets."""
    heights = [] if heights is None else heights
    c = [0.0 if s["radius_mm"] in (None, 0) else 1.0 / s["radius_mm"] for s in surfaces]
    t = [s["thickness_mm"] for s in surfaces]
    n_after = [s["n"] for s in surfaces]
    n_before = [1.0] + n_after[:-1]
    y, nu = h, 0.0
    for k in range(j):                              # forward to surface j
        heights.append((k, y))
        nu -= y * (n_after[k] - n_before[k]) * c[k]
        y += t[k] / n_after[k] * nu
    heights.append((j, y))
    nu += 2.0 * n_before[j] * y * c[j]              # reflected at j
    for m in range(j - 1, i, -1):                   # back through the surfaces between
        y += t[m] / n_after[m] * nu
        heights.append((m, y))
        nu += y * (n_before[m] - n_after[m]) * c[m]
    y += t[i] / n_after[i] * nu
    heights.append((i, y))
    nu -= 2.0 * n_after[i] * y * c[i]               # reflected at i
    y += t[i] / n_after[i] * nu
    for k in range(i + 1, len(surfaces)):           # forward out of the lens
        heights.append((k, y))
        nu -= y * (n_after[k] - n_before[k]) * c[k]
        if k < len(surfaces) - 1:
            y += t[k] / n_after[k] * nu
    return y, nu / n_after[-1]


def test_a_singlets_ghost_focus_spot_and_peak_agree_with_a_paraxial_trace(tmp_path):
    """An equiconvex N-BK7 singlet (R = 60 mm, 6 mm thick, f/15, the image at its paraxial focus): its one
    two-reflection ghost (back face, then front face) converges 3.7 mm behind the lens and spreads over
    ~10 mm on the 1.24 mm detector. Against a paraxial y-nu trace (independent of the code: the index is the
    import's, the rest is the file's numbers): its focus, its power on the detector (R^2 of the nominal
    image, times the detector's share of a uniform defocused disk), its RMS radius (a uniformly lit disk:
    r / sqrt 2) and its peak irradiance over the nominal image's (the nominal image, ~5 um across, falls
    within one 3 x 3 block of cells). The peak was 3.7x too high when it was the largest 3 x 3 block mean of a
    map with ~9 rays a cell (the noise's maximum)."""
    import tomllib

    from straylight.analyses.ghost_trace import MAP_BINS, PEAK_CELLS
    from straylight.cli.main import main

    lens = tmp_path / "singlet.seq"
    lens.write_text(SINGLET_SEQ)
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "lens")]) == 0
    assert main(["ghosts", str(tmp_path / "lens" / "scene.toml"), "--seed", "3", "--out", str(tmp_path / "g")]) == 0
    surfaces = json.loads((tmp_path / "lens" / "prescription.json").read_text())["surfaces"]
    assert [(s["radius_mm"], s["thickness_mm"]) for s in surfaces] == [(60.0, 6.0), (-60.0, 57.0436)]
    n = surfaces[0]["n"]
    scene = tomllib.loads((tmp_path / "lens" / "scene.toml").read_text())
    r_det = next(p for p in scene["part"] if p["name"] == "image")["surface"]["outer_radius_mm"]
    image_mm, h = 57.0436, 2.0
    y, u = _paraxial_ghost(surfaces, 1, 0, h)
    focus = -y / u - image_mm                        # from the detector, along the light
    spread = abs(y + image_mm * u)                   # the ghost's radius on the detector's plane
    R = ((n - 1) / (n + 1)) ** 2                     # Fresnel at normal incidence (the paraxial rays)
    fraction = R * R * (r_det / spread) ** 2
    cell_mm2 = (2 * r_det / MAP_BINS) ** 2
    peak = R * R / (math.pi * spread ** 2) / (1.0 / (PEAK_CELLS ** 2 * cell_mm2))  # over the nominal's P / 9 cells
    rows = json.loads((tmp_path / "g" / "ghosts.json").read_text())["ghosts"]
    assert len(rows) == 1 and rows[0]["surfaces"] == ["s2", "s1"]
    g = rows[0]
    assert g["focus_mm"] == pytest.approx(focus, abs=0.01)
    assert g["fraction_of_nominal"] == pytest.approx(fraction, rel=0.05)
    assert g["radius_mm"] == pytest.approx(r_det / math.sqrt(2), rel=0.03)
    assert g["peak_ratio"] == pytest.approx(peak, rel=0.12)


def test_every_ghost_of_a_stopped_down_cooke_triplet_focuses_where_a_paraxial_trace_puts_it(tmp_path):
    """The Cooke triplet of the corpus stopped down to f/25 (its EPD 10 -> 2 mm, so the ghosts' waists are their
    paraxial foci): each of its 15 two-reflection ghosts against the paraxial y-nu trace of the same reflections
    (:func:`_paraxial_ghost`, from prescription.json's radii, thicknesses, indices and clear apertures):
    - its focus within 1 % of the distance (measured: 0.02-0.6 mm of 30-92 mm, the residual aberrations);
    - its power over the nominal image's within 8 % (measured 0.94-1.02): R_i R_j (normal-incidence Fresnel)
      times T^2 of each surface crossed twice more, times the share of the beam every clear aperture on the
      way passes, min over the crossings of (semi-diameter / y)^2 (a centred beam scaled linearly), times the
      detector's share of the ghost's disk (all of it here). Three ghosts reflected last at the first surface
      keep only 28-48 % of their beam that way."""
    import tomllib

    from straylight.cli.main import main

    lens = tmp_path / "cooke_f25.seq"
    text = (LENSES / "optiland" / "cooke_triplet.seq").read_text()
    assert "EPD 10.0" in text
    lens.write_text(text.replace("EPD 10.0", "EPD 2.0"))
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "lens")]) == 0
    assert main(["ghosts", str(tmp_path / "lens" / "scene.toml"), "--field-deg", "0", "--out", str(tmp_path / "g")]) == 0
    surfaces = json.loads((tmp_path / "lens" / "prescription.json").read_text())["surfaces"]
    index = {s["name"]: k for k, s in enumerate(surfaces)}
    rows = json.loads((tmp_path / "g" / "ghosts.json").read_text())["ghosts"]
    assert len(rows) == 15
    n_after = [s["n"] for s in surfaces]
    n_before = [1.0] + n_after[:-1]
    fresnel = [((a - b) / (a + b)) ** 2 for a, b in zip(n_after, n_before)]
    h = json.loads((tmp_path / "lens" / "prescription.json").read_text())["epd_mm"] / 2
    r_det = next(p for p in tomllib.loads((tmp_path / "lens" / "scene.toml").read_text())["part"]
                 if p["name"] == "image")["surface"]["outer_radius_mm"]
    clipped = 0
    for row in rows:
        j, i = (index[name] for name in row["surfaces"])
        y, u = _paraxial_ghost(surfaces, j, i)
        focus = -y / u - surfaces[-1]["thickness_mm"]
        assert row["focus_mm"] == pytest.approx(focus, rel=0.01), row["surfaces"]
        heights: list = []
        y, u = _paraxial_ghost(surfaces, j, i, h, heights)
        y_det = y + surfaces[-1]["thickness_mm"] * u
        apertures = min(1.0, *((surfaces[k]["semi_diameter_mm"] / abs(yk)) ** 2 for k, yk in heights))
        clipped += apertures < 0.9
        between = math.prod((1 - fresnel[m]) ** 2 for m in range(i + 1, j))
        share = fresnel[i] * fresnel[j] * between * apertures * min(1.0, (r_det / abs(y_det)) ** 2)
        assert row["fraction_of_nominal"] == pytest.approx(share, rel=0.08), row["surfaces"]
    assert clipped >= 3  # the check sees the clear apertures, not only the Fresnel products


def _far_window():
    """A window (n = 1.5, faces of radius 10 mm at z = 10 and 0) 100 mm below its source (radius 10 mm)."""
    scene, src, mats = window_scene(face_radius_mm=10.0, source_z_mm=110.0, source_radius_mm=10.0)
    return ResolvedScene(None, scene, mats, (src,), ())


def test_a_turned_field_moves_the_source_over_the_lens():
    """``--field-deg`` turns the source; a source far in front of its lens must also move, or the turned beam
    misses the lens (a wide-angle lens's 63 deg edge crosses the source plane ~50 mm off axis). At 30 deg the beam
    from 100 mm above the window lands 58 mm off axis: before, no ray reached the detector. Now the source covers
    the light that enters the window at the scene source's irradiance E = 1 W / (pi 10^2): the design path carries
    E x the overlap of the two faces' disks as the refracted beam sees them (shifted by t tan(theta_t) inside the
    glass) x (T_s^2 + T_p^2) / 2 (Fresnel, Born & Wolf 1.5.3; the exit's T equals the entry's)."""
    f = math.radians(30.0)
    opt = prepare(_far_window(), field_deg=30.0)
    table = ghost_table(opt, target_rel_error=0.01)
    n, r, t = 1.5, 10.0, 10.0
    ft = math.asin(math.sin(f) / n)
    rs = (math.sin(f - ft) / math.sin(f + ft)) ** 2
    rp = (math.tan(f - ft) / math.tan(f + ft)) ** 2
    shift = t * math.tan(ft)
    overlap = 2 * r * r * math.acos(shift / (2 * r)) - 0.5 * shift * math.sqrt(4 * r * r - shift * shift)
    want = overlap / (math.pi * 10.0 ** 2) * ((1 - rs) ** 2 + (1 - rp) ** 2) / 2
    nominal = table.nominal
    assert abs(nominal.power_w - want) < 4 * nominal.stderr_w + 1e-3 * want, (nominal.power_w, nominal.stderr_w, want)
    assert opt.source.power_w > 1.0  # the same irradiance over a larger disk
    assert len(table.rows) == 1 and table.rows[0].surfaces == ["bottom", "top"]


def test_a_mirror_system_is_refused_in_one_line_and_the_process_exits_2(tmp_path):
    """poke's PLOS Cassegrain (two mirrors, CODE V): `ghosts` printed its one-line refusal, then the process
    aborted at exit ("pure virtual method called", exit 134): the embree scene built for the refused scene was
    freed at the interpreter's teardown. Now the refusal comes before the scene is built, and a failed command's
    leftovers are collected before it returns. A separate process: the abort was at its exit."""
    import subprocess
    import sys

    from straylight.cli.main import main

    assert main(["optics", "import", str(LENSES / "poke" / "PLOS_CassegrainJonesPupil.seq"), "--out",
                 str(tmp_path / "lens")]) == 0
    run = subprocess.run([sys.executable, "-m", "straylight.cli.main", "ghosts", str(tmp_path / "lens" / "scene.toml"),
                          "--out", str(tmp_path / "g")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 2, (run.returncode, run.stderr[-500:])
    assert run.stderr.strip().splitlines() == [
        "straylight: error: the scene has no lens or window (no dielectric part: a mirror system), so no ghost"]
