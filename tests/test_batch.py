"""``shoha batch``: one row per item, resumable, the same on a process pool and on Dask.

The saves are made from the reference by optimizer/perturb.py (deterministic),
plus one bad save. The Dask tests start a real ``distributed.LocalCluster``
with two worker processes.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from geometry.errors import InputError
from geometry.layout import read_layout, write_layout
from optimizer.batch import (
    OPTIMIZE_COLUMNS,
    SCORE_COLUMNS,
    TIMING_COLUMNS,
    Item,
    RowFile,
    expand_saves,
    parse_seeds,
    run_batch,
    score_task,
)
from tests.conftest import ROOT, shoha
from tests.perturb import trainee_saves

REFERENCE = Path(__file__).parent / "data" / "mini-reference.json"
SAVES = 10  # and one bad save; save 9 carries a named fault


def make_saves(folder: Path, count: int, seed: int = 0) -> list[Path]:
    """``count`` saves perturbed from the reference, the same every time, and one bad save."""
    folder.mkdir(parents=True, exist_ok=True)
    ref = read_layout(REFERENCE)
    paths = []
    for name, layout in trainee_saves(ref.load_scene(), ref, count, seed=seed):
        layout.scene = "mini"
        path = folder / f"{name}.json"
        write_layout(layout, path)
        paths.append(path)
    bad = folder / "broken-save.json"
    bad.write_text('{"format": "shoha-layout/1", "scene": "mini", "blocks": [{"id": 0}]}')
    return [*paths, bad]


def rows_of(path: Path) -> dict[str, dict]:
    """Rows by item, timing columns dropped; fails on a duplicate item."""
    rows = RowFile(path, SCORE_COLUMNS).read()
    out = {}
    for row in rows:
        assert row["item"] not in out, f"{row['item']} twice"
        out[row["item"]] = {k: v for k, v in row.items() if k not in TIMING_COLUMNS}
    return out


@pytest.fixture(scope="module")
def saves(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("batch") / "saves"
    make_saves(folder, SAVES)
    return folder


@pytest.fixture(scope="module")
def pool_rows(saves, tmp_path_factory) -> dict[str, dict]:
    """The batch on a local pool of 2 processes, through the CLI."""
    out = tmp_path_factory.mktemp("pool") / "scores.csv"
    r = shoha("batch", "score", str(saves), "--reference", str(REFERENCE), "--out", str(out),
              "--workers", "2", "--json", timeout=900)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["items"] == SAVES + 1 and summary["ran"] == SAVES + 1 and summary["errors"] == 1
    return rows_of(out)


def test_every_save_has_one_row_and_the_bad_one_an_error(pool_rows, saves):
    assert set(pool_rows) == {str(p) for p in sorted(saves.glob("*.json"))}
    bad = pool_rows[str(saves / "broken-save.json")]
    assert bad["status"] == "error" and "broken-save.json" in bad["error"] and bad["score"] == ""
    good = [r for k, r in pool_rows.items() if "broken" not in k]
    assert all(r["status"] == "ok" for r in good)
    assert all(0.0 <= float(r["score"]) <= 100.0 for r in good)
    # Every tenth save carries a named fault; the first of them is a lifted block.
    lifted = next(r for k, r in pool_rows.items() if "lift_out_of_tolerance" in k)
    assert int(lifted["out_of_tolerance"]) >= 1


def test_pool_matches_a_single_process(pool_rows, saves, tmp_path):
    out = tmp_path / "scores.jsonl"
    items = [Item(str(p), {"save": str(p), "reference": str(REFERENCE)})
             for p in sorted(saves.glob("*.json"))]
    summary = run_batch(items, score_task, RowFile(out, SCORE_COLUMNS), workers=1)
    assert summary.ran == len(items) and summary.runner == "this process"
    rows = rows_of(out)
    # JSON Lines keep types and the full result; compare on the CSV's columns as text.
    as_csv = RowFile(tmp_path / "x.csv", SCORE_COLUMNS)
    assert SCORE_COLUMNS[-1] == "seconds"
    for key, row in rows.items():
        got = next(csv.reader([as_csv.line(row).decode()]))
        expected = next(csv.reader([as_csv.line(pool_rows[key]).decode()]))
        assert got[:-1] == expected[:-1], key  # every column but seconds
        if row["status"] == "ok":
            assert row["result"]["score"] == row["score"]


def test_rerun_skips_done_items_and_a_changed_save_is_scored_again(saves, tmp_path):
    folder = tmp_path / "few"
    folder.mkdir()
    for p in sorted(saves.glob("save-000[0-2]*.json")):
        (folder / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "scores.csv"
    args = ("batch", "score", str(folder), "--reference", str(REFERENCE), "--out", str(out), "--json")
    first = json.loads(shoha(*args).stdout)
    assert (first["ran"], first["skipped"]) == (3, 0)
    again = json.loads(shoha(*args).stdout)
    assert (again["ran"], again["skipped"]) == (0, 3)
    changed = sorted(folder.glob("*.json"))[0]
    layout = read_layout(changed)
    layout.blocks = layout.blocks[:-1]
    write_layout(layout, changed)
    third = json.loads(shoha(*args).stdout)
    assert (third["ran"], third["skipped"]) == (1, 2)
    rows = RowFile(out, SCORE_COLUMNS).read()
    assert len(rows) == 4 and rows[-1]["item"] == str(changed) and rows[-1]["blocks"] == "74"


def test_killed_batch_resumes_without_losing_or_repeating_items(saves, pool_rows, tmp_path):
    out = tmp_path / "scores.csv"
    cmd = [str(Path(sys.executable).parent / "shoha"), "batch", "score", str(saves), "--reference",
           str(REFERENCE), "--out", str(out), "--workers", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if out.exists() and len(out.read_text().splitlines()) >= 1 + 3:  # header and 3 rows
                break
            time.sleep(0.1)
        assert proc.poll() is None, "the batch finished before it could be interrupted"
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its pool: a power cut, as far as it knows
    finally:
        proc.wait(timeout=60)
    partial = rows_of(out)
    assert 3 <= len(partial) < SAVES + 1
    r = shoha(*cmd[1:], "--json", timeout=900)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["skipped"] == len(partial) and summary["ran"] == SAVES + 1 - len(partial)
    assert rows_of(out) == pool_rows


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as c, distributed.Client(c) as client:
        yield c, client


def test_dask_matches_the_pool_and_survives_a_killed_worker(cluster, saves, pool_rows, tmp_path):
    c, client = cluster
    out = tmp_path / "scores.csv"
    cmd = [str(Path(sys.executable).parent / "shoha"), "batch", "score", str(saves), "--reference",
           str(REFERENCE), "--out", str(out), "--scheduler", c.scheduler_address, "--json"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    killed = None
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and killed is None:
            busy = {w: tasks for w, tasks in client.processing().items() if tasks}
            rows = len(out.read_text().splitlines()) - 1 if out.exists() else 0
            if rows >= 1 and busy:
                worker = sorted(busy)[0]
                pid = client.run(os.getpid, workers=[worker])[worker]
                os.kill(pid, signal.SIGKILL)  # a worker dies in the middle of a task
                killed = (worker, busy[worker])
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert killed is not None, "no worker was killed mid-task"
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    assert summary["ran"] == SAVES + 1 and summary["runner"].startswith("dask")
    assert rows_of(out) == pool_rows


TINY = ROOT / "tests" / "data" / "tiny.toml"


def test_a_scheduler_address_is_host_and_port():
    """``--scheduler``: any scheme or none, a name, an IPv4 or a bracketed IPv6 host, and a port
    (``tcp://[::1]:8786`` was refused as no address)."""
    from optimizer.batch import check_scheduler

    for address in ("tcp://127.0.0.1:8786", "tcp://[::1]:8786", "TCP://sched.example:8786", "host:1",
                    "tls://[fe80::1]:8786", None):
        check_scheduler(address)
    for address in ("garbage", "tcp://[::1]", "tcp://host", "tcp://host:123456", "tcp://a b:1", "tcp://[x]:1"):
        with pytest.raises(InputError, match="not a scheduler address"):
            check_scheduler(address)


def test_batch_input_errors(tmp_path, saves):
    base = ["batch", "score", str(saves), "--reference", str(REFERENCE)]
    notes = tmp_path / "notes.csv"
    notes.write_text("my notes\n")
    cases = [
        (["batch", "score", str(tmp_path / "nothing-*.json"), "--reference", str(REFERENCE),
          "--out", str(tmp_path / "o.csv")], "no saves match"),
        ([*base, "--out", str(tmp_path / "o.txt")], ".csv"),
        (["batch", "score", str(saves), "--reference", str(tmp_path / "none.json"),
          "--out", str(tmp_path / "o.csv")], "none.json"),
        ([*base, "--out", str(tmp_path / "o.csv"), "--scheduler", "tcp://127.0.0.1:9"], "cannot connect"),
        ([*base, "--out", str(tmp_path / "o.csv"), "--scheduler", "garbage"], "not a scheduler address"),
        (["batch", "optimize", "mini", "--layouts", str(tmp_path / "l"), "--out", str(tmp_path / "o.csv"),
          "--scheduler", "garbage"], "not a scheduler address"),
        (["batch", "optimize", "no-such-scene", "--layouts", str(tmp_path / "l"), "--out",
          str(tmp_path / "o.csv")], "no-such-scene"),
        (["batch", "optimize", "mini", "--seeds", "5-2", "--layouts", str(tmp_path / "l"), "--out",
          str(tmp_path / "o.csv")], "seeds"),
        (["batch", "optimize", "mini", "--time-limit", "nan", "--layouts", str(tmp_path / "l"), "--out",
          str(tmp_path / "o.csv")], "--time-limit nan"),
        (["batch", "optimize", "mini", "tiny-no", "mini", "--layouts", str(tmp_path / "l"), "--out",
          str(tmp_path / "o.csv")], "tiny-no"),
        (["batch", "optimize", "mini", "mini", "--layouts", str(tmp_path / "l"), "--out",
          str(tmp_path / "o.csv")], "mini: its layouts would be written over those of mini"),
        (["batch", "optimize", str(TINY), f"{TINY.parent}/../data/{TINY.name}", "--layouts",
          str(tmp_path / "l"), "--out", str(tmp_path / "o.csv")], "tiny-seedN.json"),
        # Refused once the run has begun to read: the layouts' folder was made by then.
        (["batch", "optimize", "mini", "--layouts", str(tmp_path / "l"), "--out", str(notes)],
         "its columns are not those of this batch"),
        (["batch", "optimize", "mini", "--layouts", str(tmp_path / "l"), "--out", str(tmp_path / "o.csv"),
          "--scheduler", "tcp://127.0.0.1:9"], "cannot connect"),
        # Names a socket cannot even look up (the IDNA codec refuses an empty label).
        ([*base, "--out", str(tmp_path / "o.csv"), "--scheduler", "tcp://a..b:8786"], "cannot connect"),
        ([*base, "--out", str(tmp_path / "o.csv"), "--scheduler", "[::1]:9"], "cannot connect"),
    ]
    for args, word in cases:
        r = shoha(*args, timeout=120)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.splitlines()  # not stripped: an empty line above the refusal is a second line
        assert len(lines) == 1 and word in lines[0], lines
        assert not (tmp_path / "o.csv").exists() or (tmp_path / "o.csv").stat().st_size == 0
        assert not (tmp_path / "l").exists()  # the layouts' folder is made only for a run


def test_another_reference_is_refused(tmp_path, saves):
    out = tmp_path / "o.csv"
    one = sorted(saves.glob("save-0000*.json"))[0]
    assert shoha("batch", "score", str(one), "--reference", str(REFERENCE), "--out", str(out)).returncode == 0
    other = tmp_path / "other-reference.json"
    layout = read_layout(REFERENCE)
    layout.blocks = layout.blocks[:-1]
    write_layout(layout, other)
    r = shoha("batch", "score", str(one), "--reference", str(other), "--out", str(out))
    assert r.returncode == 2 and "another reference" in r.stderr


def test_row_file_cuts_a_torn_last_line_and_refuses_other_files(tmp_path):
    out = tmp_path / "rows.csv"
    f = RowFile(out, SCORE_COLUMNS)
    f.append({"item": "a", "status": "ok", "score": 90.0, "stable": True})
    f.append({"item": "b", "status": "error", "error": 'bad, "quoted"\nsecond line'})
    whole = out.read_bytes()
    with open(out, "ab") as fh:
        fh.write(b"c,ok,,c.json,12")  # a write cut short
    rows = f.read()
    assert [r["item"] for r in rows] == ["a", "b"] and out.read_bytes() == whole
    assert rows[0]["stable"] == "true" and rows[1]["error"] == 'bad, "quoted"\nsecond line'
    other = tmp_path / "other.csv"
    other.write_text("name,value\nx,1\n")
    with pytest.raises(InputError):
        RowFile(other, SCORE_COLUMNS).read()
    lines = tmp_path / "rows.jsonl"
    lines.write_text('{"item": "a"}\nnot json\n')
    with pytest.raises(InputError):
        RowFile(lines, SCORE_COLUMNS).read()
    lines.write_text("[" * 100_000 + "\n")  # deeper than the JSON reader recurses: exit 1 before
    with pytest.raises(InputError, match="line 1 is not JSON"):
        RowFile(lines, SCORE_COLUMNS).read()
    good = RowFile(lines, SCORE_COLUMNS).line({"item": "a", "status": "ok"}).decode()
    for bad in ('{"item": NaN}', '{"item": 3}', '{"item": null}', '{"score": 1}', '{"item": "b"}'):
        lines.write_text(good + bad + "\n")
        with pytest.raises(InputError, match="line 2 is not a row of this batch"):
            RowFile(lines, SCORE_COLUMNS).read()
    # The other kind of batch's rows (and a torn one after them) are refused, and left as they are.
    scores = RowFile(tmp_path / "scores.jsonl", SCORE_COLUMNS)
    scores.append({"item": "a.json", "status": "ok", "score": 90.0})
    text = scores.path.read_bytes() + b'{"item": "b.js'
    scores.path.write_bytes(text)
    with pytest.raises(InputError, match="line 1 is not a row of this batch"):
        RowFile(scores.path, OPTIMIZE_COLUMNS).read()
    assert scores.path.read_bytes() == text
    with pytest.raises(InputError):
        RowFile(tmp_path / "rows.txt", SCORE_COLUMNS)
    # One line that is not this batch's, without its newline, is no torn row: it stays (it was cut).
    for name, text in (("notes.jsonl", b"my important notes"), ("notes.csv", b"foo bar"),
                       ("notes.csv", b"\x00\xff\xfe"), ("header.csv", b"item,status\nx")):
        other = tmp_path / name
        other.write_bytes(text)
        with pytest.raises(InputError):
            RowFile(other, SCORE_COLUMNS).read()
        assert other.read_bytes() == text
    # A first write cut short is cut, as any torn line is.
    for name, text in (("torn.csv", b"item,status,er"), ("torn.jsonl", b'{"item": "a", "sta'),
                       ("t.jsonl", b'{"it')):
        torn = tmp_path / name
        torn.write_bytes(text)
        assert RowFile(torn, SCORE_COLUMNS).read() == [] and torn.read_bytes() == b""


@pytest.mark.parametrize("text, seeds", [("0-3", [0, 1, 2, 3]), ("1,4,7", [1, 4, 7]),
                                         ("0-2,10", [0, 1, 2, 10]), ("3,3", [3]), ("5", [5])])
def test_parse_seeds(text, seeds):
    assert parse_seeds(text) == seeds


# 0-99999999999 made its whole list first: a MemoryError, exit 1.
# 1_0 and an Arabic-Indic 3 were read as 10 and 3; 99999999999999999999 ran, where optimize --seed stops.
@pytest.mark.parametrize("text", ["", "a", "3-1", "-1", "1-2-3", "0-100000", "0-99999999999",
                                  "0-99999,100001", "1_0", "\u0663", "99999999999999999999"])
def test_parse_seeds_rejects(text):
    with pytest.raises(InputError):
        parse_seeds(text)


def test_expand_saves(tmp_path):
    (tmp_path / "a.json").write_text("{}")
    (tmp_path / "b.json").write_text("{}")
    (tmp_path / "c.txt").write_text("")
    ref = tmp_path / "a.json"
    assert expand_saves([str(tmp_path)]) == [str(tmp_path / "a.json"), str(tmp_path / "b.json")]
    assert expand_saves([str(tmp_path / "*.json"), str(tmp_path / "b.json")], exclude=[ref]) == \
        [str(tmp_path / "b.json")]
    with pytest.raises(InputError):
        expand_saves([str(tmp_path / "*.csv")])


@pytest.mark.slow
def test_batch_optimize_writes_layouts_and_resumes(tmp_path):
    out = tmp_path / "runs.jsonl"
    args = ("batch", "optimize", "mini", "--seeds", "0-1", "--time-limit", "5", "--layouts",
            str(tmp_path / "layouts"), "--out", str(out), "--workers", "2", "--json")
    first = json.loads(shoha(*args, timeout=1800).stdout)
    assert first["ran"] == 2
    rows = RowFile(out, ()).read()
    for row in rows:
        if row["status"] == "ok":
            assert Path(row["path"]).is_file() and read_layout(row["path"]).blocks
    again = json.loads(shoha(*args, timeout=600).stdout)
    assert (again["ran"], again["skipped"]) == (0, 2)
    assert len(out.read_text().splitlines()) == 2


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_200_saves_on_a_local_cluster_resume_and_match_the_pool(cluster, tmp_path):
    """Issue 5's acceptance: 200 saves on 2 Dask workers finish, resume after an
    interruption, and give the rows of ``--workers 2`` (benchmarks/batch_cluster.py times it)."""
    c, _ = cluster
    folder = tmp_path / "saves"
    make_saves(folder, 200)
    items = 201  # and the bad save
    common = [str(folder), "--reference", str(REFERENCE)]
    pool = tmp_path / "pool.csv"
    r = shoha("batch", "score", *common, "--out", str(pool), "--workers", "2", "--json", timeout=3000)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ran"] == items

    out = tmp_path / "dask.csv"
    cmd = [str(Path(sys.executable).parent / "shoha"), "batch", "score", *common, "--out", str(out),
           "--scheduler", c.scheduler_address]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        while proc.poll() is None:
            if out.exists() and len(out.read_text().splitlines()) - 1 >= items // 2:
                os.killpg(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.1)
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL, "the batch finished before it could be interrupted"
    before = rows_of(out)
    r = shoha(*cmd[1:], "--json", timeout=3000)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["skipped"] == len(before) and summary["ran"] == items - len(before)
    assert rows_of(out) == rows_of(pool)


def test_an_error_row_keeps_a_name_with_a_newline_whole():
    """A save named ``new\\nline.json``: its error row showed only ``bs/new``."""
    from geometry.errors import InputError
    from optimizer.batch import _error_row

    row = _error_row({"item": "x"}, InputError("bs/new\nline.json: malformed JSON at line 1 column 2"), 0.0)
    assert row["error"] == "bs/new\\nline.json: malformed JSON at line 1 column 2"
