"""scripts/results-tables on JSON samples of real runs (trimmed), against the tables expected.

    python3 -m unittest discover -s scripts/tests

The samples: eval-real.json (`flyd eval eval/real.toml --seeds 2 --only
kitti2015_train_000001,seq12_frame0,seq12_frame11 --jobs 1`), eval-hw-mock.json (`flyd eval
eval/hw-mock.toml --only pedestrian-steps-in,drive-30-to-pedestrian,drive-40-to-pedestrian
--seeds 4 --jobs 1`, drive-30-to-pedestrian removed), eval-closed-loop.json (`flyd eval
eval/closed-loop.toml --seeds 1 --only car-stationary-100-30kmh,pedestrian-stationary-vehicle-rig,
steel-plate-30kmh,bend-car-stationary-30kmh`, 2026-12-07), bench-still.json (`flyd bench --json`),
bench-driving-phases.json (`flyd bench --scenario driving --json` built with
`--features phase-timers`), bench-end-to-end.json (`flyd bench --end-to-end 10 --json`), all
2026-12-06. The expected tables were checked against what `flyd eval` and `flyd bench` print.
"""

import json
import os
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "results-tables")
FIXED = ["--date", "2026-12-06", "--machine", "AMD EPYC, 2 cores"]


def run(*args):
    out = subprocess.run([sys.executable, SCRIPT, *args], cwd=HERE, capture_output=True,
                         text=True, check=True)
    return out.stdout


def expected(name):
    with open(os.path.join(HERE, name), encoding="utf-8") as f:
        return f.read()


class Tables(unittest.TestCase):
    def test_eval_real(self):
        got = run("eval", "eval-real.json", *FIXED, "--command",
                  "flyd eval eval/real.toml --seeds 2 --only kitti2015_train_000001,"
                  "seq12_frame0,seq12_frame11 --jobs 1 --json eval-real.json")
        self.assertEqual(got, expected("expected-eval-real.md"))

    def test_eval_hw_mock(self):
        got = run("eval", "eval-hw-mock.json", *FIXED, "--command",
                  "flyd eval eval/hw-mock.toml --only pedestrian-steps-in,"
                  "drive-30-to-pedestrian,drive-40-to-pedestrian --seeds 4 --jobs 1 "
                  "--json eval-hw-mock.json",
                  "--note", "drive-30-to-pedestrian left out of this sample")
        self.assertEqual(got, expected("expected-eval-hw-mock.md"))

    def test_eval_closed_loop(self):
        got = run("eval", "eval-closed-loop.json", *FIXED, "--command",
                  "flyd eval eval/closed-loop.toml --seeds 1 --only car-stationary-100-30kmh,"
                  "pedestrian-stationary-vehicle-rig,steel-plate-30kmh,"
                  "bend-car-stationary-30kmh --json eval-closed-loop.json")
        self.assertEqual(got, expected("expected-eval-closed-loop.md"))
        self.assertIn("| car-stationary-100-30kmh | no-contact | 1 of 1 | 0 of 1 | 1.1 m (1) |",
                      got)

    def test_bench(self):
        got = run("bench", "bench-still.json", "bench-driving-phases.json",
                  "bench-end-to-end.json", *FIXED,
                  "--command", "flyd bench --json",
                  "--command", "cargo build --release --features phase-timers && "
                  "target/release/flyd bench --scenario driving --json",
                  "--command", "flyd bench --end-to-end 10 --json")
        self.assertEqual(got, expected("expected-bench.md"))

    def test_the_median_run_of_a_setting(self):
        with open(os.path.join(HERE, "bench-still.json"), encoding="utf-8") as f:
            run_ = json.load(f)
        with tempfile.TemporaryDirectory() as tmp:
            paths = []
            for us in (130.0, 110.0, 120.0):
                run_["all"]["median_us"] = us
                paths.append(os.path.join(tmp, f"{us}.json"))
                with open(paths[-1], "w", encoding="utf-8") as f:
                    json.dump(run_, f)
            got = run("bench", *paths, *FIXED, "--command", "flyd bench --json")
        row = [l for l in got.splitlines() if l.startswith("| pedestrian-4m")]
        self.assertEqual(len(row), 1, got)
        self.assertIn("| 3 | 120.0 (p95", row[0])

    def test_into_a_doc_between_markers(self):
        with tempfile.TemporaryDirectory() as tmp:
            doc = os.path.join(tmp, "doc.md")
            with open(doc, "w", encoding="utf-8") as f:
                f.write("# Doc\n\n<!-- results:real begin -->\nold\n<!-- results:real end -->\n"
                        "\nkept\n")
            run("eval", "eval-real.json", *FIXED, "--command", "C", "--into", doc,
                "--marker", "real")
            with open(doc, encoding="utf-8") as f:
                text = f.read()
        self.assertTrue(text.startswith("# Doc\n\n<!-- results:real begin -->\nMeasured "))
        self.assertNotIn("old", text)
        self.assertIn("| seq12_frame11 | stop 13.8 m ± 0.7 | 2 of 2 |", text)
        self.assertTrue(text.endswith("Every label met on seeds 1-2.\n"
                                      "<!-- results:real end -->\n\nkept\n"))

    def test_a_doc_without_its_markers_is_refused(self):
        with tempfile.TemporaryDirectory() as tmp:
            doc = os.path.join(tmp, "doc.md")
            with open(doc, "w", encoding="utf-8") as f:
                f.write("# Doc\n")
            out = subprocess.run([sys.executable, SCRIPT, "eval", "eval-real.json", *FIXED,
                                  "--command", "C", "--into", doc, "--marker", "real"],
                                 cwd=HERE, capture_output=True, text=True)
        self.assertNotEqual(out.returncode, 0)
        self.assertIn("results:real begin", out.stderr)


if __name__ == "__main__":
    unittest.main()
