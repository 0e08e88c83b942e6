"""Writes examples/data/imu_increments_rfu.csv: the input format of ``insalign-import`` on a small example.

One second of the simulated ``car`` scenario (seed 0, 100 Hz, with IMU noise and biases) as an increment-type IMU
with right-forward-up axes, GNSS fixes at 1 Hz (empty cells between them) and a reference attitude in the NED
convention (roll, pitch, heading from North) with its position. test/test_import.py converts it (and checks that
this script still writes the same file). Run:  python examples/make_import_example.py

    insalign-import examples/data/imu_increments_rfu.csv /tmp/example_bag --imu increments --axes RFU --euler ned
"""

from pathlib import Path

from insalign_ros.io.importer import table_from_scenario, write_csv
from insalign_ros.sim.scenarios import make_scenario

OUT = Path(__file__).resolve().parent / "data" / "imu_increments_rfu.csv"
OPTIONS = {"imu": "increments", "axes": "RFU", "euler": "ned"}


def example_table(duration_s: float = 1.0, seed: int = 0, scenario: str = "car"):
    return table_from_scenario(make_scenario(scenario, seed=seed, duration_s=duration_s), **OPTIONS)


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    write_csv(OUT, example_table(), comment="insalign-import example (examples/make_import_example.py): car, seed 0, "
              "1 s at 100 Hz\nimport with: --imu increments --axes RFU --euler ned")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
