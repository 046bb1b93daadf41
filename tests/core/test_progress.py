"""Progress: tqdm bars with an ETA on a terminal, plain lines (no carriage returns, no ANSI codes) elsewhere,
nothing when quiet; stage reports; the bench suite's per-run reports."""

import io
import re
import time

import pytest

from gof_warp.cli import bench
from gof_warp.cli.bench import Run, run_suite, tetra
from gof_warp.core.progress import Bar, Stages, TrainingProgress, as_stages, format_seconds, is_terminal

INFO = {"total": 0.1234, "psnr": 23.456, "num_gaussians": 9005, "l1": 0.1}
ANSI = re.compile(r"\x1b\[")


class FakeTTY(io.StringIO):
    """A terminal, as far as the progress code can tell."""

    def isatty(self):
        return True


def _train(progress, total=20, sleep=0.002):
    with progress:
        for it in range(1, total + 1):
            time.sleep(sleep)
            progress(it, INFO)


def test_terminal_gets_a_tqdm_bar_with_eta_and_the_training_numbers():
    out = FakeTTY()
    assert is_terminal(out) and not is_terminal(io.StringIO())
    _train(TrainingProgress(20, stream=out))
    text = out.getvalue()
    assert "\r" in text, "a terminal bar redraws in place"
    last = text.rstrip("\n").split("\r")[-1]
    assert re.search(r"it 100%\|.+\| 20/20 \[", last), last
    assert "ETA 00:00" in last and "it/s" in last, last
    assert "loss 0.1234 psnr 23.46 N 9005" in last, last
    assert text.endswith("\n"), "the finished bar stays on its own line"


def test_a_log_gets_plain_lines_with_eta_and_no_control_characters():
    out = io.StringIO()
    _train(TrainingProgress(20, stream=out, interval=0))
    text = out.getvalue()
    assert "\r" not in text and not ANSI.search(text)
    lines = text.splitlines()
    assert len(lines) == 20, "interval 0: one line per update"
    assert re.fullmatch(r"it 20/20 loss 0\.1234 psnr 23\.46 N 9005 [\d.]+ it/s elapsed 0:00 ETA 0:00", lines[-1]), lines[-1]
    assert re.fullmatch(r"it 5/20 .* ETA 0:0\d", lines[4]), lines[4]


def test_plain_lines_are_rate_limited_but_the_last_one_is_always_written():
    out = io.StringIO()
    _train(TrainingProgress(50, stream=out, interval=3600), total=50, sleep=0)
    lines = out.getvalue().splitlines()
    assert [line.split()[1] for line in lines] == ["1/50", "50/50"]


def test_resumed_training_counts_its_rate_from_where_it_started():
    out = io.StringIO()
    bar = Bar(100, "it", initial=90, stream=out, interval=0)
    time.sleep(0.05)
    bar.goto(95)
    assert bar.rate() < 500, "only 5 iterations were done here, not 95"
    assert 0 < bar.eta() < 5 * 0.05 * 2
    assert bar.line().startswith("it 95/100 ")


@pytest.mark.parametrize("stream", [FakeTTY, io.StringIO])
def test_quiet_writes_nothing(stream):
    out = stream()
    _train(TrainingProgress(20, stream=out, quiet=True))
    stages = Stages(out, quiet=True)
    with stages.stage("delaunay"):
        with stages.bar(3, "step") as bar:
            bar.update(3)
    assert out.getvalue() == ""
    assert set(stages.times) == {"delaunay"}, "times are recorded even when quiet"


def test_stages_write_one_line_per_stage_and_time_it():
    out = io.StringIO()
    stages = Stages(out, interval=0)
    with stages.stage("tetra"):
        with stages.stage("delaunay"):
            time.sleep(0.02)
        with stages.bar(2, "step", unit="step") as bar:
            bar.update()
            bar.update(postfix="done")
    text = out.getvalue()
    assert "\r" not in text and not ANSI.search(text)
    lines = text.splitlines()
    assert lines[0] == "tetra ..." and lines[1] == "  tetra › delaunay ..."
    assert re.fullmatch(r"  tetra › delaunay 0\.\d s", lines[2]), lines[2]
    assert lines[3].startswith("tetra › step 1/2 ") and lines[4].startswith("tetra › step 2/2 done ")
    assert re.fullmatch(r"tetra 0\.\d s", lines[5]), lines[5]
    assert stages.times["delaunay"] >= 0.02 and stages.times["tetra"] >= stages.times["delaunay"]


def test_a_failed_stage_says_so_and_the_error_propagates():
    out = io.StringIO()
    stages = Stages(out)
    with pytest.raises(RuntimeError, match="boom"):
        with stages.stage("marching"):
            raise RuntimeError("boom")
    assert re.search(r"^marching failed after 0\.0 s$", out.getvalue(), re.M), out.getvalue()


def test_stages_on_a_terminal_tick_and_show_bars_with_eta():
    out = FakeTTY()
    stages = Stages(out)
    with stages.stage("delaunay"):
        time.sleep(0.8)  # the ticking line refreshes every 0.5 s
        with stages.bar(4, "search") as bar:
            for _ in range(4):
                time.sleep(0.21)  # a terminal bar redraws at most every 0.2 s
                bar.update()
    text = out.getvalue()
    assert "\rdelaunay 0:0" in text, "the stage's ticking line"
    assert re.search(r"delaunay › search 100%\|.+\| 4/4 \[.*ETA", text), text
    assert re.search(r"\rdelaunay 1\.\d s\n$", text), "the stage's last line stays"


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="total"):
        Bar(-1)
    with pytest.raises(ValueError, match="interval"):
        Stages(io.StringIO(), interval=-1)
    with pytest.raises(ValueError, match="name"):
        with Stages(io.StringIO()).stage(""):
            pass
    assert as_stages(None).quiet and as_stages(s := Stages(io.StringIO())) is s


def test_format_seconds():
    assert [format_seconds(x) for x in (0, 59.4, 75.2, 3725, float("nan"), -1)] == ["0:00", "0:59", "1:15", "1:02:05",
                                                                                   "?", "?"]


def test_bench_reports_each_run_as_a_stage_with_its_training_and_extractions(tmp_path, monkeypatch):
    def fake_training(run, run_dir, device, data=None, progress=None):
        for it in range(1, 11):
            progress(it, {"total": 0.5, "psnr": 20.0, "num_gaussians": 7})
        return object(), None, None, {"iterations": 10}, run_dir

    monkeypatch.setattr(bench, "_train_or_load", fake_training)
    monkeypatch.setattr(bench, "_extract_row", lambda run, method, model, *a: {
        "run": run.name, "iteration": model.iteration, "method": method.name, "scene": run.preset})
    monkeypatch.setattr(bench, "write_charts", lambda *a: [])
    runs = [Run(name, "default", (8, 8), 2, overrides={"iterations": 10}, methods=(tetra(0), tetra(1)))
            for name in ("first", "second")]
    out = io.StringIO()
    run_suite("tiny", tmp_path, runs=runs, stages=Stages(out, interval=3600))
    lines = out.getvalue().splitlines()
    assert lines[0] == "run first ..." and lines[-1].startswith("run second ") and lines[-1].endswith(" s")
    assert any(re.fullmatch(r"run first › it 10/10 loss 0\.5000 psnr 20\.00 N 7 .* ETA 0:00", x) for x in lines), lines
    assert any(re.fullmatch(r"run second › extract 2/2 @10 tetra_bs1 .*", x) for x in lines), lines
    assert "\r" not in out.getvalue()
