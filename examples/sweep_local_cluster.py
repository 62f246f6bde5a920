"""Sweep drive-cycle scenarios of an FMU on Dask: cycles × ambient temperatures × start SoC.

    python examples/sweep_local_cluster.py CELL.fmu [--scheduler tcp://HOST:8786]

Without --scheduler it starts a LocalCluster with one worker process per core on this machine.
On a cluster: start `dask scheduler` on one machine and `dask worker tcp://HOST:8786` on each
of the others (each with LMNCell installed from a clone: `pip install -e '.[sweep]'`), then give
that address; the FMU itself is sent to the workers. The same from the command line:

    lmncell sweep CELL.fmu --cycles wltc,us06,udds,hwfet --ambient 0,25,40 --soc0 0.9,0.5 \\
        --out results.csv --plot sweep-plots [--scheduler tcp://HOST:8786]
"""

from __future__ import annotations

import argparse

import lmncell
from lmncell.cli import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("fmu", help="an LMNCell FMU")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="a running Dask scheduler (default: a LocalCluster here)")
    a = ap.parse_args()
    table = lmncell.sweep(a.fmu, cycles=["wltc", "us06"], ambient_c=[0.0, 25.0, 40.0],
                          soc0=[0.9, 0.5], scheduler=a.scheduler)
    print(table[["cycle", "ambient_c", "soc0", "voltage_min_v", "soc_end",
                 "cell_temperature_max_c", "wall_s"]].to_string(index=False))


if __name__ == "__main__":
    run_script(main, __file__)
