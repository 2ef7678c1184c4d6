"""``roger bench teach``: the page's latency and rates with a real browser on a real session.

Starts ``roger teach`` as a person runs it (realtime, rendered vision), opens its page in
headless Chromium (Playwright, Debian's ``/usr/bin/chromium``) and presses keys on it:
``--presses`` key presses (walk and turn keys, each held ~0.1 s, ``--gap`` s apart), then
reads what the session measured:

* **key press -> simulator**: from the browser's key event (``performance.timeOrigin +
  event.timeStamp``, the same wall clock as the server's) to the command's receipt by the
  simulator's loop (``received``) and to the tick that executes it (``executed``; the loop
  steps at 30 Hz, so this adds up to one tick), p50 and p99;
* **page refresh**: the states the page received per second (the browser counts them);
* **daemon**: the predictions per second the session received from ``roger daemon`` and the
  loop's ticks per second, over the last two seconds, sampled every second during the run.

Targets (issue 54): key press -> received p99 <= 50 ms, page >= 10 Hz, daemon still at 30 Hz.
The machine's load average is reported beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["configure", "run"]

KEYS = ("KeyW", "KeyQ", "KeyE", "KeyS")
TARGETS = {"key_to_received_p99_ms": 50.0, "page_hz": 10.0, "daemon_hz": 30.0}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench teach``."""
    parser.add_argument("--presses", type=int, default=100, help="key presses (default 100)")
    parser.add_argument("--gap", type=float, default=0.25, metavar="S",
                        help="seconds between presses (default 0.25)")
    parser.add_argument("--vision", choices=("rendered", "fast"), default="rendered",
                        help="the simulator's vision (default rendered, as roger teach's)")
    parser.add_argument("--chromium", default=os.environ.get("ROGER_CHROMIUM",
                                                             "/usr/bin/chromium"),
                        help="the browser (default /usr/bin/chromium)")
    parser.add_argument("--screenshot", type=Path, metavar="PNG",
                        help="also save a screenshot of the page at the end (docs/figures/"
                             "teach.png is one)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def _measure(url: str, args: argparse.Namespace) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright

    samples: list[dict[str, float]] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=args.chromium, headless=True,
                                     args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1280, "height": 700})
        page.goto(url)
        page.wait_for_function("window.teach && window.teach.stats.states > 10",
                               timeout=60_000)
        states0, t0 = page.evaluate("window.teach.stats.states"), time.monotonic()
        last_sample = t0
        for i in range(args.presses):
            key = KEYS[i % len(KEYS)]
            page.keyboard.down(key)
            time.sleep(0.1)
            page.keyboard.up(key)
            time.sleep(max(0.0, args.gap - 0.1))
            if time.monotonic() - last_sample >= 1.0:
                last_sample = time.monotonic()
                samples.append(page.evaluate("window.teach.state.rates_hz"))
        states1, t1 = page.evaluate("window.teach.stats.states"), time.monotonic()
        time.sleep(0.5)
        state = page.evaluate("window.teach.state")
        if args.screenshot is not None:
            page.keyboard.down("KeyW")  # the page while a key is held
            time.sleep(0.6)
            page.screenshot(path=str(args.screenshot))
            page.keyboard.up("KeyW")
        browser.close()
    lat = state["latency_ms"]
    preds = [s["predictions"] for s in samples[2:]] or [0.0]
    ticks = [s["ticks"] for s in samples[2:]] or [0.0]
    return {
        "key_to_received_ms": {"p50": lat["received_p50"], "p99": lat["received_p99"]},
        "key_to_executed_ms": {"p50": lat["applied_p50"], "p99": lat["applied_p99"]},
        "commands_measured": lat["n"],
        "page_hz": round((states1 - states0) / (t1 - t0), 2),
        "daemon_predictions_hz": {"mean": round(float(np.mean(preds)), 2),
                                  "min": round(float(np.min(preds)), 2)},
        "loop_ticks_hz": {"mean": round(float(np.mean(ticks)), 2),
                          "min": round(float(np.min(ticks)), 2)},
        "overruns": state["counts"].get("overruns", 0), "ticks": state["tick"],
        "daemon_level": state.get("daemon", {}).get("level", "?"),
    }


def run(args: argparse.Namespace) -> int:
    """Measure; print a table or ``--json``; 0 (1 if a target was missed)."""
    from simulator.teach.experiment import start_teach, stop_teach

    if not Path(args.chromium).exists():
        print(f"roger bench teach: no browser at {args.chromium} (apt-get install chromium)")
        return 2
    with tempfile.TemporaryDirectory(prefix="roger-bench-teach-") as tmp:
        out = Path(tmp)
        proc, url = start_teach(out, "--vision", args.vision)
        try:
            result = _measure(url, args)
        finally:
            code = stop_teach(proc)
    met = {"key_to_received_p99_ms": (result["key_to_received_ms"]["p99"] or 1e9)
           <= TARGETS["key_to_received_p99_ms"],
           "page_hz": result["page_hz"] >= TARGETS["page_hz"],
           "daemon_hz": result["daemon_predictions_hz"]["mean"] >= TARGETS["daemon_hz"] - 1.0}
    result.update({"targets": TARGETS, "met": met, "teach_exit": code,
                   "load_average": [round(v, 2) for v in os.getloadavg()],
                   "presses": args.presses, "vision": args.vision})
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:24} {v}")
    return 0 if all(met.values()) else 1
