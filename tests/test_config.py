"""The configuration file: whatever is wrong with it is one line naming the file (and the line
or the field), exit code 4, never a traceback; `config --check` refuses what a run would."""

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli_errors import assert_one_line_error

from bimgraph.cli import app
from bimgraph.config import Config, default_yaml

runner = CliRunner()


def check(path):
    return runner.invoke(app, ["config", "--check", str(path)])


@pytest.mark.parametrize("content, message", [
    (b"backend:\n  noise: [1, 2\n  x: 3\n", "bad.yaml: line 3: invalid YAML (expected ',' or ']', but got ':')"),
    (b"backend:\n\tnoise: 1\n", "bad.yaml: line 2: invalid YAML (found character '\\t' that cannot start any token)"),
    (b"\x7fELF\x02\x01\x01\x00\x00\x00\xf0\x9f\x00\x00", "bad.yaml: not a text file"),
    (b"\xff\xfebinary", "bad.yaml: not a text file"),
    (b"sim:\x00 1\n", "bad.yaml: invalid YAML (special characters are not allowed)"),
    (b"- a\n- b\n", "bad.yaml: (top level): Input should be a valid dictionary"),
])
def test_a_file_that_is_not_a_configuration_is_one_line(tmp_path, content, message):
    (tmp_path / "bad.yaml").write_bytes(content)
    assert_one_line_error(check(tmp_path / "bad.yaml"), 4, message)


def test_a_missing_configuration_file_is_one_line(tmp_path):
    assert_one_line_error(check(tmp_path / "none.yaml"), 4, "none.yaml: no such file")


@pytest.mark.parametrize("yaml, message", [
    ("sim:\n  observe:\n    min_range_m: 6\n    max_range_m: 5\n", "sim.observe: min_range_m (6.0) is above max_range_m (5.0)"),
    ("depth_noise:\n  min_range_m: 8\n", "depth_noise: min_range_m (8.0) is above max_range_m (7.0)"),
    ("depth_noise:\n  grazing_start_deg: 86\n", "depth_noise: grazing_start_deg (86.0) is above grazing_end_deg (85.0)"),
    ("planes:\n  min_depth_m: 9\n", "planes: min_depth_m (9.0) is above max_depth_m (7.0)"),
    ("deviations:\n  visibility_min_range_m: 6\n", "deviations: visibility_min_range_m (6.0) is above visibility_max_range_m (5.0)"),
    ("sim:\n  width: 1\n", "sim: width and height (1x480) must be at least observe.stride_px (4)"),
    ("deviations:\n  tolerance_m: 20\n", "deviations.tolerance_m: Input should be less than or equal to 1"),  # (mm)
    ("sim:\n  frontend:\n    scale_error: 2\n", "sim.frontend.scale_error: Input should be less than 0.5"),
    ("sim:\n  trajectory:\n    pitch_mean_deg: .nan\n", "sim.trajectory.pitch_mean_deg: Input should be a finite number"),
    ("sim:\n  trajectory:\n    height_min_m: 2.0\n    height_max_m: 1.0\n", "sim.trajectory: height_min_m (2.0) is above height_max_m (1.0)"),
    # (both passed and then failed the run: an overflow, an array of 30 GiB)
    ("backend:\n  noise:\n    odometry_trans_m: 1.0e+300\n", "backend.noise.odometry_trans_m: Input should be less than or equal to 1000"),
    ("deviations:\n  visibility_grid_m: 1.0e-9\n", "deviations.visibility_grid_m: Input should be greater than or equal to 0.01"),
    # a value of the wrong type is refused, not converted (true was a tolerance of 1 m)
    ("deviations:\n  tolerance_m: true\n", "deviations.tolerance_m: Input should be a valid number"),
    ("deviations:\n  tolerance_m: \"0.05\"\n", "deviations.tolerance_m: Input should be a valid number"),
    ("backend:\n  write_every: true\n", "backend.write_every: Input should be a valid integer"),
    ("deviations:\n  online_refine: 1\n", "deviations.online_refine: Input should be a valid boolean"),
    # (passed, and `bimgraph bim` kept every sliver)
    ("bim:\n  min_face_area_m2: -1\n", "bim.min_face_area_m2: Input should be greater than or equal to 0"),
    # a key given twice: PyYAML kept the last one silently
    ("bim:\n  min_face_area_m2: 0.1\n  min_face_area_m2: 0.2\n",
     "line 3: invalid YAML (key 'min_face_area_m2' given twice, first on line 2)"),
    ("bim: {threads: 1, threads: 2}\n", "line 1: invalid YAML (key 'threads' given twice, first on line 1)"),
    ("bim:\n  threads: 1\nsim: {}\nbim:\n  include_slabs: true\n", "line 4: invalid YAML (key 'bim' given twice, first on line 1)"),
])
def test_check_refuses_what_a_run_could_not_use(tmp_path, yaml, message):
    (tmp_path / "c.yaml").write_text(yaml)
    assert_one_line_error(check(tmp_path / "c.yaml"), 4, f"c.yaml: {message}")


def test_a_section_keeps_the_defaults_of_the_keys_the_file_leaves_out(tmp_path):
    """The site scenario's as-built defaults differ from `AsBuiltConfig`'s: a file that sets one
    of them keeps the site's others."""
    from bimgraph.config import load_config

    path = tmp_path / "c.yaml"
    path.write_text("sim:\n  as_built_site:\n    offset_fraction: 0.2\nbackend:\n  noise:\n    bim_offset_m: 0.02\n")
    cfg, default = load_config(path), Config()
    assert cfg.sim.as_built_site == default.sim.as_built_site.model_copy(update={"offset_fraction": 0.2})
    assert cfg.sim.as_built_site.clutter_per_m2 == 0.08 and cfg.sim.as_built_site.partitions == 3
    assert cfg.backend.noise == default.backend.noise.model_copy(update={"bim_offset_m": 0.02})
    assert cfg.backend.offline == default.backend.offline


def test_integers_for_floats_and_lists_for_ranges_are_what_yaml_writes(tmp_path):
    from bimgraph.config import load_config

    path = tmp_path / "c.yaml"
    path.write_text("deviations:\n  k_sigma: 2\nsim:\n  initial_rot_error_deg: [1, 3.5]\n")
    cfg = load_config(path)
    assert cfg.deviations.k_sigma == 2.0 and cfg.sim.initial_rot_error_deg == (1.0, 3.5)


def test_a_merge_key_may_be_overridden(tmp_path):
    """A merge (`<<:`) and then a key it brought is YAML's way to override it, not a key given twice."""
    from bimgraph.config import load_config

    path = tmp_path / "c.yaml"
    path.write_text("deviations:\n  <<: {tolerance_m: 0.03, k_sigma: 4}\n  k_sigma: 2\n")
    cfg = load_config(path)
    assert cfg.deviations.k_sigma == 2.0 and cfg.deviations.tolerance_m == 0.03


def test_the_default_configuration_is_valid(tmp_path):
    (tmp_path / "default.yaml").write_text(default_yaml())
    result = check(tmp_path / "default.yaml")
    assert result.exit_code == 0 and "valid" in result.output
    (tmp_path / "empty.yaml").write_text("")
    assert check(tmp_path / "empty.yaml").exit_code == 0


def test_simulate_with_an_image_too_small_is_refused_before_anything_is_written(tmp_path):
    """It was a pydantic ValidationError traceback from the coarse camera, after the model was written."""
    (tmp_path / "c.yaml").write_text("sim:\n  width: 1\n")
    result = runner.invoke(app, ["simulate", "-o", str(tmp_path / "seq"), "-n", "3", "-c", str(tmp_path / "c.yaml")])
    assert_one_line_error(result, 4, "width and height (1x480)")
    assert not (tmp_path / "seq").exists()


def test_plane_cells_larger_than_the_image_are_a_configuration_error():
    from bimgraph.errors import ConfigError
    from bimgraph.planes.extractor import PlaneExtractor
    from bimgraph.sequence.format import Camera

    cfg = Config()
    with pytest.raises(ConfigError, match="planes.cell_size_px: cells of 20 px leave fewer than 2x2 cells in the camera's 30x30 image"):
        PlaneExtractor(Camera(width=30, height=30, fx=30, fy=30, cx=15, cy=15), cfg.planes, cfg.depth_noise)


def test_a_config_from_a_pipe_is_read(tmp_path):
    """`--config <(...)` (the shell's pipe) and `/dev/null` were refused as "no such file";
    files that are read whole (IFC, images) still need a regular one, and say so."""
    import os
    import threading

    from bimgraph.config import load_config
    from bimgraph.errors import InputError
    from bimgraph.files import existing_file

    fifo = tmp_path / "config.fifo"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_text("backend:\n  isam2:\n    judge_every: 7\n"))
    writer.start()
    assert load_config(fifo).backend.isam2.judge_every == 7
    writer.join()
    assert load_config(Path("/dev/null")) == Config()
    with pytest.raises(InputError, match="config.fifo: not a regular file"):
        existing_file(fifo)
