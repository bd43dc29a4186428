"""The imported scene focuses where the lens file's own sequential trace puts the image (CONTRACTS-style rule of
docs/optics.md): on axis and at the field's edge, of the power near focus (on a disk 3 x the geometric spot
radius about the sequential centroid), >= 95 % (85 % at the edge) falls within 1.2 x the geometric spot
radius; on axis, the encircled power at half the sequential 90 % radius is within 0.05 of the sequential one.

The sequential trace is rayoptics' real-ray trace of the same file (straylight.optics.sequential), an
independent code path from our non-sequential tracer.
"""
import math
from pathlib import Path

import numpy as np
import pytest

LENSES = Path(__file__).resolve().parent / "data" / "lenses"
FAST = ["ray-optics/ag_dblgauss.seq", "ray-optics/rc_f16.seq", "optiland/lens1.zmx",
        "OpticsDatabase/Fujifilm_Fujinon_XF27mm_F2.8.zmx",  # two extended odd aspheres (r^3 ... r^19 terms)
        "OpticsDatabase/Fujifilm_Fujinon-SW_65mm_F5.6.zmx"]  # two glasses of one nd.vd label, 1.69359 and 1.69350
SLOW = ["optiland/cooke_triplet.seq", "ray-optics/CODV_32327.seq", "ray-optics/HoO-V2C18Ex03.zmx", "ray-optics/US08011793-1.zmx",
        "OpticsDatabase/Edmund_32-299.zmx", "OpticsDatabase/Edmund_45-206.zmx", "ray-optics/landscape_lens.seq",
        "ray-optics/paraboloid.seq", "ray-optics/questar35.seq", "ray-optics/threemir.seq",
        "ray-optics/schmidt.seq", "ray-optics/mangin.seq", "ray-optics/354710-C.zmx", "ray-optics/dec_tilt_test.seq",
        "optiland/lens_thorlabs_iso_8859_1.zmx", "ray-optics/zmax_37992.zmx", "optiland/mirror.seq",
        "optiland/one_mirror_up_45deg.zmx", "ray-optics/HoO-V2C18Ex27.zmx", "ray-optics/asp46.seq",
        "ray-optics/ACL3026U.zmx", "optiland/fno_fields.seq", "OpticsDatabase/Nikon_Reflex-Nikkor-C_500mm_F8.zmx",
        "OpticsDatabase/Canon_EF50mm_f1.0L_USM.zmx",  # r^2 terms on flat bases: paraboloids
        "OpticsDatabase/Fujifilm_Fujinon_XF23mm_F1.4_R.zmx",
        "OpticsDatabase/Samyang_50mm_F1.4_AS_UMC.zmx",  # two elements in contact: one interface between the glasses
        "OpticsDatabase/Nikon_1_Nikkor_10mm_f2.8.zmx",  # 69 of 3000 sequential rays pass: sampled again, finer
        "OpticsDatabase/Wray_64mm_F0.7.zmx",  # real image height fields (FTYP 3): the edge angle is the aimed chief ray's
        "OpticsDatabase/TH_Swiss_Irix_11mm_f4.0.zmx",  # 63 deg edge: steep segments just in front of steep surfaces
        "ray-optics/US05331467-1.zmx",  # a rear element in its own glass through a Mangin primary's front
        "ray-optics/HoO-V2C18Ex66.zmx",  # four off-axis mirrors: a beam grazing one side of s3 (no hole)
        # the stop's beam fills ~1 % of the source disk: 4 of 6000 scene rays reached the image before (passing_disk)
        "OpticsDatabase/Kinoptik_Tegea_5.7mm_f1.8.zmx",
        "OpticsDatabase/Topcon_35-100mm_F3.5-4.3.zmx",  # a zoom (its first configuration), 39 of 6000 before
        "ZOSPy/Prism_using_total_internal_reflection.zmx"]  # coordinate breaks inside the prism's glass


#: the map's cells per radius of the encircled-power disk (r90 / 2) at least: a coarser map counts whole cells
#: in or out of the disk (HoO-V2C18Ex66 on axis, r90 / 2 ~6 cells of 121: 0.397 against the sequential 0.452;
#: with 241 bins 0.447)
CELLS_PER_RADIUS = 12
MAX_BINS = 481


def focus_check(lens, field_deg, tmp_path, rays=6000, bins=None):
    """(inside, ee_scene, ee_seq, r_geo) of ``lens`` imported at ``field_deg``: the reference is the sequential trace
    over the disk its passing rays start from (:func:`passing_disk`); ``inside`` the smaller of the fractions of
    the scene's power near focus within 1.2 r_geo with the scene's own source (light around the lens groups from
    anywhere on it) and with the source narrowed to that disk; ``ee_scene`` from the narrowed trace."""
    import copy

    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene
    from straylight.optics.sequential import sequential_spot

    p = read_prescription(lens)
    scene = build_scene(p, field_deg=field_deg)
    src = scene["source"][0]
    centre, radius = passing_disk(p, field_deg, src)
    seq = sequential_spot(p, field_deg, src["center_mm"][2], radius, n=3000, source_centre_xy=centre, min_kept=300)
    assert len(seq) > 50
    c = seq.mean(axis=0)
    dist = np.linalg.norm(seq - c, axis=1)
    r_geo = max(float(dist.max()), 1e-3)
    r90 = float(np.quantile(dist, 0.9))
    if bins is None:  # the map spans 6 r_geo
        bins = int(min(MAX_BINS, max(121, math.ceil(6.0 * r_geo * CELLS_PER_RADIUS / max(0.5 * r90, 1e-12))))) | 1
    det = next(part for part in scene["part"] if part["name"] == "image")
    det["surface"]["vertex_mm"] = [float(v) for v in c]
    det["surface"]["outer_radius_mm"] = 3.0 * r_geo
    whole, _ = _map_fractions(scene, tmp_path / "whole", rays, bins, c, (1.2 * r_geo, 0.5 * r90), lens, field_deg)
    narrow = copy.deepcopy(scene)
    narrow["source"][0]["center_mm"] = [float(centre[0]), float(centre[1]), float(src["center_mm"][2])]
    narrow["source"][0]["radius_mm"] = float(radius)
    inside, ee_scene = _map_fractions(narrow, tmp_path / "narrow", rays, bins, c, (1.2 * r_geo, 0.5 * r90), lens,
                                      field_deg)
    ee_seq = float(np.mean(dist <= 0.5 * r90))
    return min(whole, inside), ee_scene, ee_seq, r_geo


def passing_disk(p, field_deg, src, n=3000, min_kept=300, max_n=60_000):
    """(centre (x, y), radius) mm of the disk on the source plane that the sequential rays passing the lens start
    from, plus two steps of the sequential grid. The beam the stop passes can fill a few % of the ``pupil`` source
    (1.1 x the largest clear aperture): traced over the whole disk, 6000 scene rays put 4 (Kinoptik Tegea 5.7 mm)
    to 73 on the image, so the encircled power was a binomial of that many (0.500 against 0.409; 0.385-0.391 over
    the passing disk against a fine reference's 0.382), and the reference's 88-400 rays put its edge a grid step
    inside the beam's (its r_geo 61 um against 86)."""
    from straylight.optics.sequential import sequential_paths

    z, r = src["center_mm"][2], src["radius_mm"]
    cxy = src["center_mm"][:2]
    paths = sequential_paths(p, field_deg, z, r, n, source_centre_xy=cxy)
    if 0 < len(paths) < min_kept and n < max_n:
        n = int(min(max_n, n * 1.2 * min_kept / len(paths)))
        paths = sequential_paths(p, field_deg, z, r, n, source_centre_xy=cxy)
    assert len(paths) > 50, f"{len(paths)} sequential rays pass"
    starts = np.array([path[0][:2] for path in paths])
    step = 2.0 * r / (max(int(math.sqrt(4.0 * n / math.pi)), 3) - 1)  # straylight.optics.sequential.pupil_grid's
    centre = starts.mean(axis=0)
    return centre, float(np.max(np.linalg.norm(starts - centre, axis=1))) + 2.0 * step


def _map_fractions(scene, directory, rays, bins, c, radii, lens, field_deg):
    """Fractions of the power on the detector map of ``scene`` traced with ``rays`` within each of ``radii`` of c."""
    from straylight.engine.options import OutputOptions, TraceOptions
    from straylight.optics.output import scene_toml
    from straylight.scene import load_scene

    directory.mkdir(parents=True, exist_ok=True)
    (directory / "scene.toml").write_text(scene_toml(scene, "focus test"))
    res = load_scene(directory / "scene.toml").trace(rays, seed=1,
                                                     options=TraceOptions(output=OutputOptions(map_bins=(bins, bins))))
    m = res.maps["image"]
    uc = 0.5 * (np.asarray(m.edges_u_mm)[1:] + np.asarray(m.edges_u_mm)[:-1])
    vc = 0.5 * (np.asarray(m.edges_v_mm)[1:] + np.asarray(m.edges_v_mm)[:-1])
    U, V = np.meshgrid(uc, vc, indexing="ij")
    pts = np.asarray(m.origin_mm)[None, None, :] + U[..., None] * np.asarray(m.axis_u) + V[..., None] * np.asarray(m.axis_v)
    rad = np.linalg.norm(pts - c, axis=-1)
    power = np.asarray(m.power_w)
    total = float(power.sum())
    assert total > 0, f"{lens.name}: no power near the sequential focus at {field_deg} deg"
    return tuple(float(power[rad <= r].sum()) / total for r in radii)


def _check(name, tmp_path):
    from straylight.optics.reader import read_prescription

    lens = LENSES / name
    p = read_prescription(lens)
    edge = max(p.fields_deg) if p.fields_deg else 0.0
    # "on axis": the file's first field, which is 0 but for a field-biased off-axis design (US08011793-1: 13..19 deg)
    centre = 0.0 if not p.fields_deg or min(p.fields_deg) == 0.0 else p.fields_deg[0]
    inside, ee_scene, ee_seq, r_geo = focus_check(lens, centre, tmp_path)
    assert inside >= 0.95, f"{name} at {centre} deg: {inside:.3f} of the power within 1.2 x r_geo = {1.2 * r_geo:.3g} mm"
    # a spot below 1 um (a paraboloid on axis) is not resolved by the map: its encircled power is not compared
    assert r_geo <= 1e-3 or abs(ee_scene - ee_seq) <= 0.05, f"{name}: encircled power at r90/2 {ee_scene:.3f} vs {ee_seq:.3f}"
    if edge > centre:
        (tmp_path / "edge").mkdir()
        inside, _, _, r_geo = focus_check(lens, edge, tmp_path / "edge")
        assert inside >= 0.85, f"{name} at {edge} deg: {inside:.3f} within 1.2 x r_geo = {1.2 * r_geo:.3g} mm"


@pytest.mark.parametrize("name", FAST)
def test_imported_scene_focuses_like_the_sequential_trace(name, tmp_path):
    _check(name, tmp_path)


def test_a_catadioptric_with_mangin_mirrors_focuses_like_the_sequential_trace(tmp_path):
    """The Reflex-Nikkor-C 500 mm: two Mangin mirrors (written as media of index -1), its last element cemented
    in the primary's centre (the primary's front surface met again between other glasses: its own part over that
    centre). Before, no sequential ray passed (the primary's glass filled its mirror's hole), then no power reached
    the sequential focus (the cemented centre refracted as air against glass)."""
    lens = LENSES / "OpticsDatabase" / "Nikon_Reflex-Nikkor-C_500mm_F8.zmx"
    inside, ee_scene, ee_seq, r_geo = focus_check(lens, 0.0, tmp_path)
    assert inside >= 0.95 and abs(ee_scene - ee_seq) <= 0.05, (inside, ee_scene, ee_seq, r_geo)


KNOWN: dict = {  # files that import but whose focus check does not pass yet (reported, not hidden)
}


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN[n], strict=False))
                                  if n in KNOWN else n for n in SLOW])
def test_every_importing_file_focuses_like_the_sequential_trace(name, tmp_path):
    _check(name, tmp_path)


def test_a_rear_element_cemented_in_a_mangin_primary_of_its_own_glass_focuses(tmp_path):
    """The Canon New FD 500mm f8 Mirror (OpticsDatabase): its rear element (s16, glass 516.641) is cemented in the
    Mangin primary's centre, of the primary's own glass, so the primary's front met again (s17) has that glass on
    both sides: no part. The primary's front part (s3, air against glass) covered its centre, so the light from
    the secondary, already in the rear element's glass, refracted there as from air: no sequential ray passed, and
    ghosts' nominal image was 1.6 mm RMS, 42 mm out of focus. The part now leaves that centre open."""
    lens = LENSES / "OpticsDatabase" / "Canon_New_FD_500mm_f8_Mirror.zmx"
    inside, ee_scene, ee_seq, r_geo = focus_check(lens, 0.0, tmp_path)
    assert inside >= 0.95 and abs(ee_scene - ee_seq) <= 0.05, (inside, ee_scene, ee_seq, r_geo)


def test_a_rear_group_inside_a_hole_through_a_mangin_primary_focuses(tmp_path):
    """The Nikon AI Reflex-Nikkor 1000mm f11 (OpticsDatabase): its rear group (s14-s17, z 168-174 mm) sits inside
    the Mangin primary (front s4 at z 165, mirror back s6 at z 175), whose glass the file gives no hole. The light
    from the secondary crossed the primary's front in air on its way to the rear group: no sequential ray passed,
    and ghosts' nominal image was 2.6 mm RMS, 211 mm out of focus. The glass now has the mirror's hole."""
    lens = LENSES / "OpticsDatabase" / "Nikon_AI_Reflex-Nikkor_1000mm_f11.zmx"
    inside, ee_scene, ee_seq, r_geo = focus_check(lens, 0.0, tmp_path)
    assert inside >= 0.95 and abs(ee_scene - ee_seq) <= 0.05, (inside, ee_scene, ee_seq, r_geo)


@pytest.mark.parametrize("name", ["OpticsDatabase/Canon_Extender_EF2X.zmx",
                                  "OpticsDatabase/Nikon_AF-I_Teleconverter_TC-20E.zmx"])
def test_a_teleconverter_keeps_no_light_around_its_smaller_middle_group(name, tmp_path):
    """Teleconverters whose middle group is smaller than the front one: without the barrel's spacer rings
    (scene_build._spacer_rings) light passed around that group through the air, 0.87 and 0.94 of the power
    within 1.2 x the sequential spot on axis (CONTRACTS 8.1 asks 0.95); with them 0.99. (Their encircled power at
    half r90 is not compared: the sequential trace is limited by a dummy surface the scene does not have,
    docs/optics.md.)"""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    lens = LENSES / name
    assert any(part["name"].startswith("spacer_") for part in build_scene(read_prescription(lens))["part"])
    inside, _, _, r_geo = focus_check(lens, 0.0, tmp_path)
    assert inside >= 0.95, f"{name}: {inside:.3f} of the power within 1.2 x r_geo = {1.2 * r_geo:.3g} mm"


def test_a_small_stop_is_sampled_again_more_finely():
    """sequential_spot's ``min_kept``: behind a wide source disk a small stop passes few rays (the Nikon 1 Nikkor
    10 mm f/2.8: ~2 % of them), and the coarse grid misses the pupil's edge, where the spot is widest (r_geo 2.9 um
    from 69 rays, ~5 um from a few hundred: the imported scene read 0.87 of its power within 1.2 x r_geo). Too few
    kept rays, and the disk is sampled again with proportionally more."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene
    from straylight.optics.sequential import sequential_spot

    p = read_prescription(LENSES / "OpticsDatabase" / "Nikon_1_Nikkor_10mm_f2.8.zmx")
    src = build_scene(p)["source"][0]
    args = (p, 0.0, src["center_mm"][2], src["radius_mm"])
    coarse = sequential_spot(*args, n=300, source_centre_xy=src["center_mm"][:2])
    fine = sequential_spot(*args, n=300, source_centre_xy=src["center_mm"][:2], min_kept=60)
    assert 0 < len(coarse) < 60 <= len(fine)
    r = [float(np.linalg.norm(s - s.mean(axis=0), axis=1).max()) for s in (coarse, fine)]
    assert r[1] >= r[0]  # the finer grid reaches at least as far toward the pupil's edge
