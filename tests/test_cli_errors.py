"""A stated error (a bad key, a bad file, device=cuda without CUDA, an unsupported glTF
input) prints one line naming the key or file and exits with status 2, with no traceback
(eval.common.errors; issue 25, item 4). Each CLI is run as installed, with one bad input."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

BIN = Path(sys.executable).parent

CASES = {
    "gspi-data import.glb=README.md": (["gspi-data", "import.glb=README.md", "out={tmp}/d"], "README.md: not a .glb"),
    "gspi-data import.glb=": (["gspi-data", "import.glb=", "out={tmp}/d"], "import.glb is empty"),
    "gspi-eval": (["gspi-eval", "gt={tmp}/no_gt", "pred={tmp}/no_pred", "out={tmp}/e"], "no_gt: no scene.json"),
    "gspi-train": (["gspi-train", "data={tmp}/no_data", "out={tmp}/t", "stage2=tiny"], "no_data/splits.json"),
    "gspi-extract": (["gspi-extract", "asset={tmp}/none.ply", "out={tmp}/x"], "none.ply: asset file not found"),
    "gspi-relight": (["gspi-relight", "asset={tmp}/none.ply", "env=meadow", "out={tmp}/r"],
                     "none.ply: asset file not found"),
    "gspi-export asset=": (["gspi-export", "asset={tmp}/none.ply", "out={tmp}/a.glb"], "none.ply: asset file not found"),
    "gspi-table": (["gspi-table", "{tmp}/no_runs", "out={tmp}/tb"], "no_runs: run folder not found"),
    "gspi-report": (["gspi-report", "{tmp}/no_runs", "out={tmp}/rp"], "run folder(s) not found"),
    "gspi-run bad key": (["gspi-run", "data={tmp}/d", "out={tmp}/o", "scene_workers=0"], "scene_workers"),
}
# Path keys with characters Hydra's grammar does not take unquoted (eval.common.argv): the message must
# carry the whole path, so the CLI quoted it (unquoted, Hydra refuses the override itself).
ODD = "{tmp}/a=b,c d"
CASES.update({
    "gspi-extract odd path": (["gspi-extract", f"asset={ODD}/none.ply", "out={tmp}/x"], "a=b,c d/none.ply"),
    "gspi-relight odd path": (["gspi-relight", f"asset={ODD}/none.ply", "env=meadow", "out={tmp}/r"],
                              "a=b,c d/none.ply"),
    "gspi-recon odd path": (["gspi-recon", f"scene={ODD}/scene", "out={tmp}/rc"], "a=b,c d/scene"),
    "gspi-data import.glb odd path": (["gspi-data", f"import.glb={ODD}/x.glb", "out={tmp}/d"],
                                      "a=b,c d/x.glb: no such file or folder"),
})
if not torch.cuda.is_available():
    CASES["gspi-run device=cuda"] = (["gspi-run", "data={tmp}/d", "out={tmp}/o", "device=cuda"],
                                     "device=cuda: CUDA is not available")


# Issue 40: every CLI x {missing required key, nonexistent path, empty / truncated / NaN PLY, a
# plain 3DGS file where a PBR asset is needed, a missing environment}: at most 2 lines, no traceback.
REQUIRED = {
    "gspi-run no data": (["gspi-run", "out={tmp}/o"], "data=..."),
    "gspi-run no out": (["gspi-run", "data={tmp}/none"], "out=..."),
    "gspi-eval no pred/out": (["gspi-eval", "gt={tmp}/none"], "out, pred"),
    "gspi-train no data": (["gspi-train", "out={tmp}/t"], "data=..."),
    "gspi-recon no out": (["gspi-recon", "scene={tmp}/none"], "out=..."),
    "gspi-extract no out": (["gspi-extract", "asset={tmp}/none.ply"], "out=..."),
    "gspi-relight no env": (["gspi-relight", "asset={tmp}/none.ply", "out={tmp}/r"], "env=..."),
    "gspi-export asset no out": (["gspi-export", "asset={tmp}/none.ply"], "out=..."),
    "gspi-data no out": (["gspi-data", "preset=tiny"], "out=..."),
    "gspi-import no system": (["gspi-import", "src={tmp}/a", "scene={tmp}/b", "out={tmp}/c"], "method"),
    "gspi-export system= empty": (["gspi-export", "system=", "scene={tmp}/b", "out={tmp}/c"], "method/"),
    "gspi-recon bad group": (["gspi-recon", "scene={tmp}/s", "out={tmp}/o", "recon=nope"], "recon/nope"),
}
BAD_PLY = {"empty": "not a readable PLY", "truncated": "early end-of-file", "nan": "non-finite",
           "missing": "not found"}
PLY_CLIS = {
    "gspi-extract": ["gspi-extract", "asset={ply}", "out={tmp}/x"],
    "gspi-relight": ["gspi-relight", "asset={ply}", "env=meadow", "out={tmp}/r"],
    "gspi-export": ["gspi-export", "asset={ply}", "out={tmp}/a.glb"],
    "gspi-run": ["gspi-run", "data={tmp}/none", "out={tmp}/o", "assets={ply}", "logger=none"],
}
for cli, argv in PLY_CLIS.items():
    for kind, expected in BAD_PLY.items():
        # each case its own out= (the matrix runs 4 at once: a failed job removes the folder it made,
        # which raced another job still opening its log file there)
        own_out = [a.replace("{ply}", "{tmp}/" + kind + ".ply").replace("out={tmp}/", f"out={{tmp}}/{kind}_") for a in argv]
        REQUIRED[f"{cli} {kind} ply"] = (own_out, f"{kind}.ply: " if kind != "missing" else "missing.ply")
REQUIRED.update({
    "gspi-relight plain 3DGS": (["gspi-relight", "asset={tmp}/plain3d.ply", "env=meadow", "out={tmp}/r_plain"],
                                "plain3d.ply: has no PBR attributes"),
    "gspi-export plain 3DGS": (["gspi-export", "asset={tmp}/plain3d.ply", "out={tmp}/a.glb"],
                               "plain3d.ply: has no PBR attributes"),
    "gspi-relight missing env": (["gspi-relight", "asset={tmp}/plain3d.ply", "env={tmp}/none.exr",
                                  "out={tmp}/r_env"],
                                 "none.exr' is neither an environment file"),
})


def write_bad_plys(tmp: Path) -> None:
    """empty.ply (0 bytes), truncated.ply (a header and part of a row), nan.ply (a 2DGS file
    with one NaN), plain3d.ply (a valid 3DGS file without PBR attributes)."""
    from gspi.gaussians.ply import write_3dgs_ply

    n = 20
    g = torch.Generator().manual_seed(0)
    args = (torch.randn(n, 3, generator=g), torch.randn(n, 4, generator=g), torch.randn(n, 3, generator=g) - 3,
            torch.randn(n, generator=g), torch.rand(n, 1, 3, generator=g), torch.zeros(n, 15, 3))
    write_3dgs_ply(tmp / "plain3d.ply", *args)
    (tmp / "empty.ply").write_bytes(b"")
    data = (tmp / "plain3d.ply").read_bytes()
    (tmp / "truncated.ply").write_bytes(data[:data.index(b"end_header\n") + 11 + 100])
    means = args[0].clone()
    means[3, 1] = float("nan")
    write_3dgs_ply(tmp / "nan.ply", means, *args[1:])


def run_cli_case(argv: list[str], tmp: Path) -> subprocess.CompletedProcess:
    cmd = [str(BIN / argv[0])] + [a.format(tmp=tmp) for a in argv[1:]]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1],
                          timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})


@pytest.mark.parametrize("case", sorted(CASES))
def test_stated_error_is_one_line_and_exit_2(case, tmp_path):
    argv, expected = CASES[case]
    done = run_cli_case(argv, tmp_path)
    err = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    assert "Traceback" not in done.stderr and "HYDRA_FULL_ERROR" not in done.stderr
    assert err[-1].startswith(f"{argv[0]}: error: ") and expected in err[-1], err
    assert not [line for line in err if "error" in line.lower() and line != err[-1]], err


@pytest.fixture(scope="module")
def matrix_runs(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    """Every case of REQUIRED, run as installed, 4 at a time (each is mostly Python start-up)."""
    from concurrent.futures import ThreadPoolExecutor

    tmp = tmp_path_factory.mktemp("bad")
    write_bad_plys(tmp)
    with ThreadPoolExecutor(max_workers=4) as pool:
        futures = {case: pool.submit(run_cli_case, argv, tmp) for case, (argv, _) in REQUIRED.items()}
        return {case: f.result() for case, f in futures.items()}


@pytest.mark.parametrize("case", sorted(REQUIRED))
def test_every_cli_bad_input_is_at_most_two_lines(case, matrix_runs):
    """Issue 40's matrix: no traceback, exit 2, at most 2 lines in all, the last names the key or file."""
    argv, expected = REQUIRED[case]
    done = matrix_runs[case]
    lines = [x for x in (done.stdout + done.stderr).splitlines() if x.strip()]
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    assert "Traceback" not in done.stderr and len(lines) <= 2, lines
    assert lines[-1].startswith(f"{argv[0]}: error: ") and expected in lines[-1], lines
