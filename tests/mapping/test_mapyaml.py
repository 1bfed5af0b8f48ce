"""The map_server map format (rsal.mapping.mapyaml): write/read round trip, the documented pixel
interpretation (thresholds, negate, trinary/scale/raw), and one-line errors for bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rsal.mapping.mapyaml import MapFileError, read_map, write_map


def _grid(h: int = 30, w: int = 40) -> np.ndarray:
    rng = np.random.default_rng(3)
    occ = rng.choice([-1.0, 0.0, 1.0], size=(h, w), p=[0.2, 0.6, 0.2])
    occ[0, :] = 1.0
    return occ


def test_write_then_read_is_the_same_map(tmp_path):
    occ = _grid()
    png, yml = write_map(tmp_path / "m", occ, 0.05, (-1.25, 2.5))
    assert png == tmp_path / "m.png" and yml == tmp_path / "m.yaml"
    m = read_map(yml)
    np.testing.assert_array_equal(m.occupancy, occ)
    assert (m.width, m.height, m.resolution, m.origin) == (40, 30, 0.05, (-1.25, 2.5, 0.0))
    assert m.mode == "trinary" and not m.negate and m.image == png
    # Player's convention: rows from the bottom, -1 free / 0 unknown / +1 occupied
    cells = m.cells()
    assert cells[-1].tolist() == [1] * 40  # the image's top row is the last row
    np.testing.assert_array_equal(cells[::-1], np.where(occ > 0, 1, np.where(occ == 0, -1, 0)))


def test_written_files_are_what_map_saver_writes(tmp_path):
    occ = np.array([[1.0, 0.0, -1.0, 0.9, 0.1, 0.5]])
    png, yml = write_map(tmp_path / "out.yaml", occ, 0.1, (0.0, 0.0, 0.0))
    assert png.name == "out.png"
    px = np.asarray(Image.open(png))
    assert px.dtype == np.uint8 and px.tolist() == [[0, 254, 205, 0, 254, 205]]
    text = yml.read_text()
    for line in ("image: out.png", "resolution: 0.1", "origin: [0.0, 0.0, 0.0]", "negate: 0",
                 "occupied_thresh: 0.65", "free_thresh: 0.196", "mode: trinary"):  # fmt: skip
        assert line in text.splitlines()


def _yaml(tmp_path: Path, pixels, body: str, mode: str = "L") -> Path:
    Image.fromarray(np.asarray(pixels, dtype=np.uint8), mode=mode).save(tmp_path / "img.png")
    p = tmp_path / "map.yaml"
    p.write_text("image: img.png\nresolution: 0.5\norigin: [1, 2, 0]\n" + body)
    return p


def test_trinary_thresholds_and_negate(tmp_path):
    # p = (255 - x) / 255: x=0 -> 1.0, 100 -> 0.608, 200 -> 0.216, 250 -> 0.0196
    px = [[0, 100, 200, 250]]
    m = read_map(_yaml(tmp_path, px, "occupied_thresh: 0.6\nfree_thresh: 0.2\nnegate: 0\n"))
    assert m.occupancy.tolist() == [[1.0, 1.0, -1.0, 0.0]]
    m = read_map(_yaml(tmp_path, px, "occupied_thresh: 0.6\nfree_thresh: 0.2\nnegate: 1\n"))
    assert m.occupancy.tolist() == [[0.0, -1.0, 1.0, 1.0]]  # p = x / 255
    assert m.origin == (1.0, 2.0, 0.0) and m.resolution == 0.5


def test_scale_mode_grades_between_thresholds_and_alpha_is_unknown(tmp_path):
    rgba = np.zeros((1, 3, 4), dtype=np.uint8)
    rgba[0, :, :3] = [[0, 0, 0], [255, 255, 255], [128, 128, 128]]
    rgba[0, :, 3] = [255, 255, 255]
    p = _yaml(tmp_path, rgba, "occupied_thresh: 0.65\nfree_thresh: 0.2\nmode: scale\n", mode="RGBA")
    m = read_map(p)
    mid = 0.99 * ((255 - 128) / 255 - 0.2) / (0.65 - 0.2)
    np.testing.assert_allclose(m.occupancy[0], [1.0, 0.0, mid], rtol=1e-6)
    assert m.cells()[0].tolist() == [1, -1, 0]  # a graded cell is neither free nor occupied
    rgba[0, 1, 3] = 100  # translucent: unknown in scale mode
    p = _yaml(tmp_path, rgba, "occupied_thresh: 0.65\nfree_thresh: 0.2\nmode: scale\n", mode="RGBA")
    assert read_map(p).occupancy[0, 1] == -1.0


def test_raw_mode_reads_percent(tmp_path):
    m = read_map(_yaml(tmp_path, [[0, 50, 100, 255]], "occupied_thresh: 0.65\nfree_thresh: 0.2\nmode: raw\n"))
    assert m.occupancy.tolist() == [[0.0, 0.5, 1.0, -1.0]]


@pytest.mark.parametrize(
    "body, expect",
    [
        ("resolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n", "missing key 'image'"),
        ("image: img.png\nresolutoin: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
         ":2: unknown key 'resolutoin'; did you mean 'resolution'?"),
        ("image: img.png\nresolution: -1\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
         ":2: resolution must be metres per pixel > 0"),
        ("image: img.png\nresolution: 0.05\norigin: [0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
         ":3: origin must be [x, y, yaw]"),
        ("image: nothere.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
         ":1: image 'nothere.png' not found"),
        ("image: img.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\nmode: trinry\n",
         ":6: unknown mode 'trinry'; did you mean 'trinary'?"),
        ("image: img.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.2\nfree_thresh: 0.6\n",
         "free_thresh 0.6 must be below occupied_thresh 0.2"),
        ("image: img.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\nnegate: 2\n",
         ":6: negate must be 0 or 1"),
        ("image: [img.png\n", "not valid YAML"),
        ("- image\n", "must be a mapping of keys"),
    ],
)  # fmt: skip
def test_bad_yaml_is_one_line_naming_the_place(tmp_path, body, expect):
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8)).save(tmp_path / "img.png")
    p = tmp_path / "bad.yaml"
    p.write_text(body)
    with pytest.raises(MapFileError) as e:
        read_map(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)) and expect in msg, msg


def test_missing_file_and_unreadable_image(tmp_path):
    with pytest.raises(MapFileError, match="no such map file"):
        read_map(tmp_path / "none.yaml")
    (tmp_path / "img.png").write_text("not a png")
    p = tmp_path / "m.yaml"
    p.write_text("image: img.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n")
    with pytest.raises(MapFileError, match=r"m.yaml:1: image 'img.png' is not a readable image"):
        read_map(p)


def test_write_rejects_bad_grids(tmp_path):
    with pytest.raises(MapFileError, match="non-empty 2-D"):
        write_map(tmp_path / "x", np.zeros(3), 0.05, (0, 0))
    with pytest.raises(MapFileError, match="finite"):
        write_map(tmp_path / "x", np.full((2, 2), 2.0), 0.05, (0, 0))
    with pytest.raises(MapFileError, match="resolution"):
        write_map(tmp_path / "x", np.zeros((2, 2)), 0.0, (0, 0))


# ------------------------------------------------------------------ where a map_server YAML loads
MAPS = Path(__file__).resolve().parents[2] / "maps"


def _serve(filename: Path, extra: str = ""):
    """The grid a ``mapfile`` driver serves (its ``rpc/get`` answer), over an in-memory session."""
    import mrs_bridge.drivers  # noqa: F401  (registers the drivers)
    from mrs_bridge.config import parse_config
    from mrs_bridge.server import DeviceServer
    from rsal.msgs import MapData
    from rsal.testing import FakeSession

    text = f'[[driver]]\nname = "mapfile"\nprovides = ["m:map:0"]\nfilename = "{filename.as_posix()}"\n{extra}'
    cfg = parse_config(text, source="map.toml", base_dir=filename.parent)
    server = DeviceServer(cfg, FakeSession())  # type: ignore[arg-type]
    try:
        server.start()
        (slot,) = server.slots
        return MapData.from_dict(slot.driver.on_rpc(cfg.drivers[0].provides[0], "get", {}))
    finally:
        server.close()


def test_mapfile_driver_serves_a_written_map(tmp_path):
    occ = _grid(24, 36)
    _, yml = write_map(tmp_path / "built", occ, 0.1, (-2.0, -1.5, 0.0))
    m = _serve(yml)
    assert (m.width, m.height, m.resolution, m.origin) == (36, 24, 0.1, (-2.0, -1.5))
    want = np.where(occ > 0, 1, np.where(occ == 0, -1, 0))[::-1]  # rows from the bottom, unknown 0
    np.testing.assert_array_equal(m.cells, want)


def test_mapfile_driver_yaml_and_png_of_a_shipped_map_agree():
    by_yaml = _serve(MAPS / "testroom.yaml")
    by_png = _serve(MAPS / "testroom.png", "resolution = 0.05\norigin = [-5.0, -4.0]\n")
    assert (by_yaml.width, by_yaml.height, by_yaml.resolution, by_yaml.origin) == (200, 160, 0.05, (-5.0, -4.0))
    assert by_yaml.origin == by_png.origin
    np.testing.assert_array_equal(by_yaml.cells, by_png.cells)


@pytest.mark.parametrize(
    "extra, expect",
    [
        ("resolution = 0.1\n", "resolution: the map_server YAML 'm.yaml' sets this itself; remove resolution"),
        ("origin = [0, 0]\nnegate = true\n", "origin, negate: the map_server YAML 'm.yaml' sets these itself"),
    ],
)
def test_mapfile_driver_refuses_parameters_the_yaml_sets(tmp_path, extra, expect):
    from mrs_bridge.config import ConfigError

    _, yml = write_map(tmp_path / "m", np.zeros((4, 4)), 0.05, (0, 0))
    with pytest.raises(ConfigError) as e:
        _serve(yml, extra)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("map.toml: driver #1 (mapfile): ") and expect in msg


def test_mapfile_driver_names_a_bad_yaml_and_a_rotated_map(tmp_path):
    from mrs_bridge.config import ConfigError

    bad = tmp_path / "bad.yaml"
    bad.write_text("image: none.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n")
    with pytest.raises(ConfigError, match=r"^map.toml: driver #1 \(mapfile\): .*bad.yaml:1: image 'none.png' not fou"):
        _serve(bad)
    _, yml = write_map(tmp_path / "rot", np.zeros((4, 4)), 0.05, (0, 0, 0.5))
    with pytest.raises(ConfigError, match=r"origin yaw 0.5 rad is not supported"):
        _serve(yml)


def _stage_world(tmp_path: Path, props: str) -> Path:
    p = tmp_path / "w.world"
    p.write_text(f'define floorplan model ( )\nfloorplan ( name "plan" {props} )\n')
    return p


def test_stage_world_floorplan_from_a_map_server_yaml(tmp_path):
    from simulator.gridmap import GridMap
    from simulator.loader import load_world

    occ = _grid(20, 50)
    write_map(tmp_path / "m", occ, 0.1, (-3.0, 7.0, 0.0))
    spec = load_world(_stage_world(tmp_path, 'bitmap "m.yaml"'))
    fp = spec.floorplan
    assert fp is not None and fp.size is None and not spec.warnings
    assert (fp.resolution, fp.origin, fp.bitmap.name) == (0.1, (-3.0, 7.0), "m.png")
    g = GridMap.from_floorplan(fp)
    assert (g.width, g.height) == (50, 20) and g.extent == pytest.approx((-3.0, 2.0, 7.0, 9.0))
    np.testing.assert_array_equal(g.occupied, (occ > 0)[::-1])  # unknown is free space to the simulator


def test_stage_world_warns_about_placement_the_yaml_overrides(tmp_path):
    from simulator.loader import load_world

    write_map(tmp_path / "m", np.zeros((20, 50)), 0.1, (-3.0, 7.0))
    # size and centre pose that match the YAML are fine (a copied world keeps them)
    assert not load_world(_stage_world(tmp_path, 'bitmap "m.yaml" size [ 5 2 0.8 ] pose [ -0.5 8 0 0 ]')).warnings
    spec = load_world(_stage_world(tmp_path, 'bitmap "m.yaml" size [ 10 8 0.8 ]'))
    assert spec.floorplan.origin == (-3.0, 7.0)
    assert len(spec.warnings) == 1 and "size ignored, the map_server YAML 'm.yaml' places the map" in spec.warnings[0]


def test_yaml_world_floorplan_from_a_map_server_yaml_and_its_errors(tmp_path):
    from simulator.errors import WorldFileError
    from simulator.loader import load_world

    write_map(tmp_path / "m", _grid(10, 12), 0.05, (1.0, 2.0))
    w = tmp_path / "w.yaml"
    w.write_text("floorplan: {bitmap: m.yaml}\n")
    fp = load_world(w).floorplan
    assert fp is not None and (fp.resolution, fp.origin, fp.mapfile) == (0.05, (1.0, 2.0), (tmp_path / "m.yaml"))
    w.write_text("floorplan:\n  bitmap: m.yaml\n  resolution: 0.1\n")
    with pytest.raises(WorldFileError, match=r"w.yaml:3: floorplan.resolution: the map_server YAML 'm.yaml' sets"):
        load_world(w)
    with pytest.raises(WorldFileError, match=r"m.yaml:1: this is a map_server map, not a world; .*bitmap: m.yaml"):
        load_world(tmp_path / "m.yaml")
    (tmp_path / "bad.yaml").write_text("image: m.png\nresolution: 0.05\n")
    w.write_text("floorplan: {bitmap: bad.yaml}\n")
    with pytest.raises(WorldFileError) as e:
        load_world(w)
    assert str(e.value).startswith(f"{w}:1: floorplan.bitmap 'bad.yaml': missing key 'origin'")


@pytest.mark.parametrize("body", ["negate: 1\n", "negate: 0\nmode: raw\n", "negate: 0\nmode: scale\n"])
def test_simulator_and_read_map_agree_on_walls(tmp_path, body):
    """The simulator reads the format on its own (it imports nothing of ours): same walls."""
    from simulator.gridmap import GridMap
    from simulator.loader import load_world

    rng = np.random.default_rng(5)
    rgba = rng.integers(0, 256, size=(16, 20, 4), dtype=np.uint8)
    rgba[..., 3] = np.where(rng.random((16, 20)) < 0.2, 128, 255)
    p = _yaml(tmp_path, rgba, "occupied_thresh: 0.6\nfree_thresh: 0.25\n" + body, mode="RGBA")
    (tmp_path / "w.yaml").write_text(f"floorplan: {{bitmap: {p.name}}}\n")
    g = GridMap.from_floorplan(load_world(tmp_path / "w.yaml").floorplan)
    np.testing.assert_array_equal(g.occupied, read_map(p).occupied[::-1])


def test_the_documented_example_is_the_shipped_testroom_map(tmp_path):
    """docs/mapping.md's format example, saved next to maps/testroom.png, reads as maps/testroom.yaml."""
    import re

    doc = (MAPS.parent / "docs" / "mapping.md").read_text()
    example = re.search(r"```yaml\n(.*?)```", doc, re.S).group(1)
    p = MAPS / "testroom.yaml"
    (tmp_path / "testroom.png").write_bytes((MAPS / "testroom.png").read_bytes())
    (tmp_path / "doc.yaml").write_text(example)
    a, b = read_map(tmp_path / "doc.yaml"), read_map(p)
    assert (a.resolution, a.origin, a.occupied_thresh, a.free_thresh, a.mode) == (
        b.resolution, b.origin, b.occupied_thresh, b.free_thresh, b.mode
    )  # fmt: skip
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


def test_simulator_refuses_a_rotated_map_and_accepts_a_two_number_origin(tmp_path):
    from simulator.errors import WorldFileError
    from simulator.loader import load_world

    _, yml = write_map(tmp_path / "rot", np.zeros((4, 4)), 0.05, (0.0, 0.0, 0.3))
    with pytest.raises(WorldFileError, match=r"w.world:2: map 'rot.yaml': origin yaw 0.3 is not 0"):
        load_world(_stage_world(tmp_path, 'bitmap "rot.yaml"'))
    yml.write_text(yml.read_text().replace("origin: [0.0, 0.0, 0.3]", "origin: [1.5, -2]"))
    assert read_map(yml).origin == (1.5, -2.0, 0.0)
    assert load_world(_stage_world(tmp_path, 'bitmap "rot.yaml"')).floorplan.origin == (1.5, -2.0)
