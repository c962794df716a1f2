"""No output of a command is one of its inputs, and no two outputs share a path (issue 25,
class 1; docs/reliability.md, "No output is an input").

Every command checks its files in one place (``rotmod.cli._common.check_files``) before any
work; here each output of each command is made equal to each of its inputs, and to each of
its other outputs: always exit 2, one line naming both, and the input byte for byte as it was.
The check comes before any file is read, so the inputs of these cases need only exist.
"""

from __future__ import annotations

import itertools
import shutil

import pytest

from rotmod.cli import main
from rotmod.io.config import preset_path

#: Per command: its arguments (``{NAME}`` the path of an input or output below), its inputs
#: and its outputs (option -> file name), as the messages name them.
COMMANDS = {
    "profile": ("profile -s 3,0 -i {--instrument} -o {--output} --plot {--plot}",
                {"--instrument": "inst.toml"}, {"--output": "p.ecsv", "--plot": "p.png"}),
    "simulate": ("simulate -i {--instrument} --attitude {--attitude} --sky-source 1,1 -t 10 "
                 "-o {--output}", {"--instrument": "inst.toml", "--attitude": "att.ecsv"},
                 {"--output": "s.fits"}),
    "fold": ("fold {EVENTS} -o {--output} --plot {--plot}", {"EVENTS": "ev.fits"},
             {"--output": "f.fits", "--plot": "f.png"}),
    "response": ("response -i {--instrument} --attitude {--attitude} --grid celestial "
                 "-o {--output}", {"--instrument": "inst.toml", "--attitude": "att.ecsv"},
                 {"--output": "out.zarr"}),
    "reconstruct": ("reconstruct {FOLDED} {RESPONSE} -o {--output} --plot {--plot}",
                    {"FOLDED": "f.fits", "RESPONSE": "r.zarr"},
                    {"--output": "i.fits", "--plot": "i.png"}),
    "detect": ("detect {DATA} --response {--response} --catalogue-in {--catalogue-in} "
               "--attitude {--attitude} -o {--output} --ts-map {--ts-map} "
               "--first-map {--first-map} --regions {--regions}",
               {"DATA": "ev.fits", "--response": "r.zarr", "--catalogue-in": "cat.fits",
                "--attitude": "att.ecsv"},
               {"--output": "c.fits", "--ts-map": "ts.fits", "--first-map": "fm.fits",
                "--regions": "c.reg"}),
    "lightcurve": ("lightcurve {EVENTS} {CATALOGUE} -i {--instrument} --attitude {--attitude} "
                   "--intervals 3 -o {--output} --plot {--plot}",
                   {"EVENTS": "ev.fits", "CATALOGUE": "cat.fits", "--instrument": "inst.toml",
                    "--attitude": "att.ecsv"}, {"--output": "lc.fits", "--plot": "lc.png"}),
    "design": ("design -i {--instrument} -o {--output} --plot {--plot}",
               {"--instrument": "inst.toml"}, {"--output": "d.ecsv", "--plot": "d.png"}),
}

CASES = [(c, o, i) for c, (_, ins, outs) in COMMANDS.items() for o in outs for i in ins]
PAIRS = [(c, a, b) for c, (_, _, outs) in COMMANDS.items()
         for a, b in itertools.combinations(outs, 2)]


@pytest.fixture
def folder(tmp_path):
    for name in ("ev.fits", "f.fits", "att.ecsv", "cat.fits"):
        (tmp_path / name).write_bytes(name.encode() * 100)  # read by none of these cases
    shutil.copy(preset_path("paper"), tmp_path / "inst.toml")
    (tmp_path / "r.zarr").mkdir()
    (tmp_path / "r.zarr" / "zarr.json").write_text("{}")
    return tmp_path


def _snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _run(capsys, folder, command, paths):
    template, ins, outs = COMMANDS[command]
    names = {k: str(folder / v) for k, v in {**ins, **outs, **paths}.items()}
    argv = [_fill(a, names) for a in template.split()]
    before = _snapshot(folder)
    code = main([*argv, "--overwrite"])
    err = capsys.readouterr().err
    assert _snapshot(folder) == before  # every input byte for byte, nothing written
    return code, err


def _fill(arg, names):
    for key, value in names.items():
        arg = arg.replace("{" + key + "}", value)
    return arg


@pytest.mark.parametrize(("command", "output", "input_"), CASES)
def test_an_output_that_is_an_input_is_refused(capsys, folder, command, output, input_):
    code, err = _run(capsys, folder, command, {output: COMMANDS[command][1][input_]})
    last = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err, err
    assert last.startswith(f"rotmod: error: {output} ") and "is also an input of this " \
        f"command ({input_} " in last, last


@pytest.mark.parametrize(("command", "first", "second"), PAIRS)
def test_two_outputs_on_one_path_are_refused(capsys, folder, command, first, second):
    code, err = _run(capsys, folder, command, {second: COMMANDS[command][2][first]})
    last = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err, err
    assert f"rotmod: error: {second} " in last and "is also another output of this command " \
        f"({first} " in last, last


@pytest.mark.parametrize(("argv", "message"), [
    # An output inside an input folder (a response store), an output folder that would hold
    # an input, and an input on a name a store's writer uses beside the store.
    (["reconstruct", "{d}/f.fits", "{d}/r.zarr", "-o", "{d}/r.zarr/zarr.json"],
     "--output '{d}/r.zarr/zarr.json' is inside an input of this command (RESPONSE"),
    (["response", "-i", "{d}/sub/inst.toml", "-o", "{d}/sub"],
     "--output '{d}/sub' holds an input of this command (--instrument '{d}/sub/inst.toml')"),
    (["response", "-i", "{d}/out.zarr.partial", "-o", "{d}/out.zarr"],
     "--output '{d}/out.zarr' (its writer also uses '{d}/out.zarr.partial') is also an input"),
    # A preset's file is the input that -i names.
    (["design", "-i", "paper", "-o", str(preset_path("paper"))],
     "is also an input of this command (--instrument '" + str(preset_path("paper")) + "')"),
    # Two names of one file: a symbolic link to the input.
    (["fold", "{d}/link.fits", "-o", "{d}/ev.fits"],
     "--output '{d}/ev.fits' is also an input of this command (EVENTS '{d}/link.fits')"),
])
def test_inputs_reached_another_way_are_refused(capsys, folder, argv, message):
    (folder / "sub").mkdir()
    shutil.copy(folder / "inst.toml", folder / "sub" / "inst.toml")
    shutil.copy(folder / "inst.toml", folder / "out.zarr.partial")
    (folder / "link.fits").symlink_to(folder / "ev.fits")
    before = _snapshot(folder)
    code = main([a.format(d=folder) for a in argv] + ["--overwrite"])
    err = capsys.readouterr().err
    assert code == 2 and message.format(d=folder) in err.strip().splitlines()[-1], err
    assert _snapshot(folder) == before


def test_burst_outputs_made_from_the_prefix_are_checked_too(capsys, tmp_path) -> None:
    from rotmod import Instrument
    from rotmod.io import write_events
    from rotmod.montecarlo import simulate_observation
    from rotmod.sky import PointSources

    ev = simulate_observation(Instrument.paper(), PointSources([3.0], [0.0], 5.0, 122.0),
                              t_stop=20.0, seed=1)
    write_events(ev, tmp_path / "grb_1.fits")
    before = (tmp_path / "grb_1.fits").read_bytes()
    code = main([str(a) for a in ("burst", tmp_path / "grb_1.fits", "-e", "122", "--pointing",
                                  "10,10", "--interval", "5,10", "-o", tmp_path / "grb",
                                  "--overwrite")])
    err = capsys.readouterr().err
    assert code == 2 and "is also an input of this command (EVENTS" in err, err
    assert (tmp_path / "grb_1.fits").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grb_1.fits"]


def test_a_users_old_folder_survives_a_replaced_store(capsys, tmp_path) -> None:
    # The store being replaced goes to a fresh temporary name, never to '<store>.old'.
    argv = ["-q", "response", "-i", "paper", "--fov", "2", "--pixel", "1", "-n", "12", "-o",
            str(tmp_path / "r.zarr"), "--overwrite"]
    (tmp_path / "r.zarr.old").mkdir()
    (tmp_path / "r.zarr.old" / "mine.txt").write_text("the user's")
    assert main(argv) == 0
    assert main(argv) == 0  # replaces r.zarr
    capsys.readouterr()
    assert (tmp_path / "r.zarr.old" / "mine.txt").read_text() == "the user's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr", "r.zarr.old"]
