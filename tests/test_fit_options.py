"""The fit command's options: one declaration (backend/core/fit_options.py) and what it feeds, in
step: argparse of ``fit`` and ``batch``, FolderFitOptions and its FitSettings, the add-on's request
and the README's table; every option's values checked from the declaration itself."""
import argparse
import dataclasses
import io
import json
import subprocess
import sys

import pytest
import torch
from conftest import ROOT

from backend.app.cli.main import build_parser
from backend.app.environment import renderer_compiles
from backend.app.folder import FolderFitOptions, fit_reporting, fit_settings
from backend.core.fit_options import (
    AUTO_OR_NUMBER,
    BATCH_OPTIONS,
    BOX,
    CHOICE,
    FIT_OPTIONS,
    FLAG,
    MAX_SEED,
    OPTIONS,
    OUTPUT_SPP,
    TEXT,
    WHOLE,
    FitOptionError,
    check_values,
    command_line,
    markdown_table,
)
from backend.core.priors import FIT_PATTERNS, MULTIPLE_ROUGHNESS_RATIO
from backend.core.protocol import EXIT_INPUT, Reporter, decode
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.fit.search import BASE_ITERATIONS, BASE_SIZE, BLUR_ALLOWANCE_PX, FINE_ITERATIONS
from backend.fit.settings import FitSettings
from backend.init.network import INIT_CHOICES
from backend.model.camera import CameraSamples
from backend.model.render import AUTO_SUBPIXEL_BELOW_PX, subpixel_size
from blender_addon.core import backend_bridge

COMMAND_ONLY = {"help", "reflection", "transmission", "out", "example", "json_progress", "stop_on_stdin"}


def subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]


def actions(command: str) -> dict[str, argparse.Action]:
    return {action.dest: action for action in subparser(command)._actions}


def parse_fit(*words: str) -> argparse.Namespace:
    return build_parser().parse_args(["fit", "R.png", "T.png", "--out", "o", *words])


def options_of(args: argparse.Namespace) -> FolderFitOptions:
    return FolderFitOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(FolderFitOptions)})


# -- the declaration feeds argparse, FolderFitOptions and FitSettings --------------------------

@pytest.mark.parametrize("command,declared_options", [("fit", FIT_OPTIONS), ("batch", BATCH_OPTIONS)])
def test_argparse_has_each_declared_option_with_its_default_values_and_help(command, declared_options):
    found = actions(command)
    assert {dest for dest in found if dest in OPTIONS} == {o.name for o in declared_options}
    if command == "fit":
        assert set(found) - set(OPTIONS) == COMMAND_ONLY
    for option in declared_options:
        action = found[option.name]
        assert action.option_strings == [option.flag]
        assert action.default == option.default
        assert action.help.replace("%%", "%") == option.help
        if option.kind == CHOICE:
            assert tuple(action.choices) == option.choices
        elif option.kind != FLAG:
            assert action.metavar == option.metavar


def test_folder_fit_options_are_the_declared_options_and_their_defaults():
    assert [(f.name, f.default) for f in dataclasses.fields(FolderFitOptions)] == [
        (o.name, o.default) for o in FIT_OPTIONS]
    assert options_of(build_parser().parse_args(["fit", "--out", "o"])) == FolderFitOptions()


def test_the_default_options_give_the_default_fit_settings():
    settings = {f.name for f in dataclasses.fields(FitSettings)}
    targets = [o.setting for o in FIT_OPTIONS if o.setting]
    assert set(targets) <= settings and len(set(targets)) == len(targets)
    assert fit_settings(FolderFitOptions(), DEFAULT_RIG) == FitSettings(compile=renderer_compiles())


def test_the_options_without_a_setting_are_read_by_the_job():
    source = (ROOT / "backend" / "app" / "folder.py").read_text()
    for option in FIT_OPTIONS:
        if not option.setting:
            assert f"options.{option.name}" in source, option.name


# The FitSettings the code gave for these command lines before the options were declared once
# (computed then through fit_to_folder, with its fit replaced by a stand-in that kept them).
RIG = {"camera_blur_px": 1.5, "sample_rotation_deg": -4.0}
BEFORE = [
    ([], None, {}),
    (["--pattern", "twill1m", "--iterations", "40", "--size", "384", "--seed", "7"], None,
     {"pattern": "twill1m", "iterations": 40, "size": 384, "seed": 7}),
    (["--camera-blur", "1.25", "--sample-rotation", "-12.5", "--light-falloff", "none", "--spacing-warp", "none",
      "--blur-on", "subpixels"], None,
     {"camera_blur": 1.25, "sample_rotation": -12.5, "light_falloff": False, "spacing_warp": False,
      "subpixel_blur": True}),
    (["--blur-on", "auto", "--init", "prior", "--output-spp", "16", "--strict", "--device", "cpu", "--vgg-weights",
      "vgg.pt", "--crop", "0", "0", "100", "100", "--flat-field", "ff.png", "--overwrite"], None,
     {"subpixel_blur": None, "vgg_weights": "vgg.pt"}),
    (["--camera-blur", "auto", "--sample-rotation", "auto"], RIG, {"camera_blur": 1.5, "sample_rotation": -4.0}),
    (["--camera-blur", "0.5", "--sample-rotation", "3"], RIG, {"camera_blur": 0.5, "sample_rotation": 3.0}),
    ([], {"camera_blur_px": 0.0, "sample_rotation_deg": 0.0}, {}),
    (["--glow", "fit"], None, {"estimate_glow": True}),   # declared after the others
    (["--blur-ceiling", "photos"], None, {"blur_ceiling": True}),
]


@pytest.mark.parametrize("words,rig,expected", BEFORE)
def test_the_same_command_lines_give_the_same_fit_settings(words, rig, expected):
    rig = DEFAULT_RIG if rig is None else CaptureRig(**rig)
    # (whether the renderer compiles is the machine's: backend.app.environment)
    assert fit_settings(options_of(parse_fit(*words)), rig) == FitSettings(**expected, compile=renderer_compiles())


# -- every option's values, from the declaration ---------------------------------------------

def text_values(option) -> tuple[list[list[str]], list[list[str]]]:
    """(valid, invalid) command-line values of ``option``, each the words after its flag."""
    if option.kind == CHOICE:
        return [[c] for c in option.choices], [["nonesuch"]]
    if option.kind == WHOLE:
        valid = [option.lo, option.lo + 1] + ([option.hi] if option.hi is not None else [])
        invalid = [option.lo - 1, "x", "1.5"] + ([option.hi + 1] if option.hi is not None else [])
        return [[str(int(v))] for v in valid], [[str(v)] for v in invalid]
    if option.kind == AUTO_OR_NUMBER:
        valid = ["auto", f"{option.lo:g}", f"{option.hi:g}", f"{(option.lo + option.hi) / 2:g}"]
        invalid = [f"{option.lo - 0.01:g}", f"{option.hi + 0.01:g}", "x", "nan"]
        return [[v] for v in valid], [[v] for v in invalid]
    if option.kind == BOX:
        return [["0", "0", "10", "10"]], [["0", "0", "x", "10"]]
    return ([[]] if option.kind == FLAG else [["some/file.json"]]), []


TYPED_INVALID = {CHOICE: ["nonesuch", 1], WHOLE: ["5", True, 1.5], AUTO_OR_NUMBER: ["x", True], FLAG: ["yes", 1],
                 TEXT: [3], BOX: [(0, 0, 10), ("0", 0, 10, 10)]}


def typed_invalid(option) -> list:
    """Values of the wrong type, and, where the option has a range, out of it."""
    wrong = list(TYPED_INVALID[option.kind])
    if option.kind in (WHOLE, AUTO_OR_NUMBER):
        wrong.append(int(option.lo) - 1)
    if option.hi is not None:
        wrong.append(option.hi + 1)
    return wrong


def refused(command: str, flag: str, words: list[str], capsys) -> str:
    base = ["fit", "R.png", "T.png"] if command == "fit" else ["batch", "P"]
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args([*base, "--out", "o", flag, *words])
    assert exit_.value.code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize("option", FIT_OPTIONS, ids=lambda o: o.name)
def test_every_option_takes_its_valid_values_on_each_path(option):
    """Each valid value: the command lines of fit (and batch) take it, the job's check passes, and
    the add-on's command_line for it reads back as the same value."""
    for words in text_values(option)[0]:
        value = getattr(parse_fit(option.flag, *words), option.name)
        if option.batch:
            assert getattr(build_parser().parse_args(["batch", "P", "--out", "o", option.flag, *words]),
                           option.name) == value
        check_values({option.name: value})
        assert getattr(parse_fit(*command_line({option.name: value})), option.name) == value


@pytest.mark.parametrize("option", FIT_OPTIONS, ids=lambda o: o.name)
def test_every_option_refuses_bad_values_with_one_line_naming_it(option, capsys, tmp_path):
    for words in text_values(option)[1]:
        for command in ("fit", "batch") if option.batch else ("fit",):
            line = refused(command, option.flag, words, capsys)
            assert line.startswith("python -m backend ") and f"argument {option.flag}: " in line, line
    for value in typed_invalid(option):
        with pytest.raises(FitOptionError, match=f"^{option.flag}: "):
            check_values({option.name: value})
        with pytest.raises(FitOptionError, match=f"^{option.flag}: "):
            command_line({option.name: value})
    # the job (the batch's Ray tasks call it with a dict of options): bad input, exit 2, nothing written
    events = io.StringIO()
    options = FolderFitOptions(**{option.name: typed_invalid(option)[0]})
    assert fit_reporting("R.png", "T.png", tmp_path / "out", options, Reporter(json_lines=True, stream=events),
                         lambda: False) == EXIT_INPUT
    error = decode(events.getvalue().splitlines()[-1])
    assert error["kind"] == "input" and error["message"].startswith(option.flag + ": ")
    assert not (tmp_path / "out").exists()


def test_the_issue_91_examples_are_refused(capsys):
    for flag, value, needle in (("--iterations", "-3", "must be at least 1, got -3"),
                                ("--iterations", "0", "must be at least 1, got 0"),
                                ("--output-spp", "0", "must be at least 1, got 0"),
                                ("--seed", "-1", f"must be in [0, {MAX_SEED}], got -1"),
                                ("--size", "0", "must be at least 32 pixels, got 0"),
                                ("--size", "big", "expected a whole number of pixels, got 'big'")):
        assert refused("fit", flag, [value], capsys).endswith(f"argument {flag}: {needle}")


def test_an_unknown_option_name_is_refused():
    with pytest.raises(FitOptionError, match="^spp: not an option of the fit"):
        check_values({"spp": 4})


# -- the thresholds ---------------------------------------------------------------------------

def test_output_spp_lets_the_camera_blur_act_on_sub_pixels():
    assert subpixel_size(OUTPUT_SPP) > 0


def test_a_seed_past_max_seed_would_repeat_a_smaller_ones_jitter():
    jitter = [CameraSamples(DEFAULT_RIG, 8, 4, seed).jitter(0, 2)[0] for seed in (0, MAX_SEED + 1, MAX_SEED)]
    assert torch.equal(jitter[0], jitter[1]) and not torch.equal(jitter[0], jitter[2])


# -- the add-on's request ---------------------------------------------------------------------

def test_the_addon_request_is_the_declarations_command_line(tmp_path):
    request = backend_bridge.FitRequest(tmp_path / "a_R.png", tmp_path / "a_T.png", tmp_path / "out", pattern="plain",
                                        iterations=12, size=64, device="cpu", rig_json=tmp_path / "rig.json",
                                        output_spp=4)
    words = request.arguments()
    assert words[:5] == ["fit", str(tmp_path / "a_R.png"), str(tmp_path / "a_T.png"), "--out", str(tmp_path / "out")]
    args = build_parser().parse_args(words)
    assert (args.pattern, args.iterations, args.size, args.device, args.rig, args.output_spp) == (
        "plain", 12, 64, "cpu", str(tmp_path / "rig.json"), 4)
    assert args.json_progress and args.stop_on_stdin
    assert build_parser().parse_args(backend_bridge.FitRequest(tmp_path, tmp_path, tmp_path).arguments()) == \
        build_parser().parse_args(["fit", str(tmp_path), str(tmp_path), "--out", str(tmp_path), "--json-progress",
                                   "--stop-on-stdin", "--pattern", "auto"])


@pytest.mark.parametrize("field,value,needle", [("iterations", 0, "--iterations: must be at least 1, got 0"),
                                                ("size", 16, "--size: must be at least 32 pixels, got 16"),
                                                ("output_spp", -4, "--output-spp: must be at least 1, got -4")])
def test_the_addon_refuses_what_the_backend_would_before_starting_it(tmp_path, field, value, needle):
    request = backend_bridge.FitRequest(tmp_path, tmp_path, tmp_path, **{field: value})
    with pytest.raises(backend_bridge.BackendError, match=f"^{needle}$"):
        request.arguments()


def test_the_addon_reads_the_declaration_without_torch():
    probe = ("import sys\nfrom blender_addon.core import declarations\n"
             "import json\nprint(json.dumps([o.name for o in declarations.fit_options().FIT_OPTIONS]))\n"
             "print(sorted({'torch', 'bpy'} & set(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    names, heavy = done.stdout.strip().splitlines()
    assert json.loads(names) == list(OPTIONS) and heavy == "[]"


# -- the README and the figures the help quotes ------------------------------------------------

def test_the_readme_holds_the_generated_table():
    text = (ROOT / "README.md").read_text()
    start = "<!-- fit options: generated by backend.core.fit_options.markdown_table() -->\n"
    end = "\n<!-- end of fit options -->"
    assert text.count(start) == 1 and text[text.index(start) + len(start):text.index(end)] == markdown_table()
    assert "(#fit-options)" in text and "### Fit options" in text


def test_the_help_quotes_the_codes_figures():
    defaults = FitSettings()
    iterations = OPTIONS["iterations"]
    assert f"{BASE_ITERATIONS} at {BASE_SIZE} px, {FINE_ITERATIONS} at a larger" in iterations.help
    assert f"not moved for {defaults.patience} steps" in iterations.help
    searches = [defaults.first_search + k * defaults.search_every for k in range(defaults.max_searches)]
    assert f"after {searches[0]}, {searches[1]} and {searches[2]} iterations" in iterations.details
    window, gain = defaults.plateau_window, f"{100 * defaults.plateau_gain:g} %"
    assert (f"From {window} steps after the last, it ends once its best loss has gained less than {gain} over the "
            f"last {window} steps") in iterations.details
    share, steps = {2: ("a half", "two"), 3: ("a third", "three"), 4: ("a quarter", "four")}[defaults.gradient_period]
    assert f"through {share} of the film's rows" in iterations.details
    assert f"{steps} steps' gradients add up to the whole one" in iterations.details
    size = OPTIONS["size"]
    assert f"first {defaults.duel_iterations} steps" in size.details
    assert f"lower by more than {defaults.duel_margin:g}" in size.details
    assert f"{DEFAULT_RIG.film_size}" in size.help and "default: 256," in size.help
    assert f"under {AUTO_SUBPIXEL_BELOW_PX:g} render pixels" in OPTIONS["blur_on"].help
    allowance = {1.0: "1 pixel", 0.5: "half a pixel", 2.0: "2 pixels"}[BLUR_ALLOWANCE_PX]
    assert f"plus {allowance}" in OPTIONS["blur_ceiling"].help
    assert f"at most {allowance} above it" in OPTIONS["camera_blur"].details
    assert OPTIONS["init"].choices == INIT_CHOICES
    assert OPTIONS["pattern"].choices[1:] == FIT_PATTERNS
    low, high = MULTIPLE_ROUGHNESS_RATIO
    assert f"within {low:g}-{high:g} times" in (ROOT / "README.md").read_text()
