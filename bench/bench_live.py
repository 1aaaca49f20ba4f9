"""Cost of the live view to a 62.5 Hz loop: ``python bench/bench_live.py [cycles]``;
``python bench/bench_live.py run [time_scale]`` compares whole emulated runs of the line
(loop period p50/p99/max and overruns) without a live view, with one and no client, and with a
subscribed client.

A stand-in cycle (the tracking law's numpy work and the record's fields, about what
``TrackingLoop`` does between bus transactions) runs on 16 ms deadlines three ways: without a live
view, with one and no client, and with a client subscribed to every channel. Prints the cycle's own
cost (p50/p99/max, us), the cost of ``publish()`` alone, and the records the view dropped.
"""
from __future__ import annotations

import asyncio
import json
import sys
import threading
import time

import numpy as np

from swerve.tools.live import LivePublisher

PERIOD_S = 0.016


def _record(k: int) -> dict:
    t = PERIOD_S * k
    return dict(t_s=t, stamp_ns=time.time_ns(), cycle=k, period_s=PERIOD_S,
                cmd_drive_radps=np.full(4, 2.0), cmd_steer_rad=np.full(4, 0.1),
                meas_drive_radps=np.full(4, 1.9), meas_steer_rad=np.full(4, 0.09),
                meas_current_a=np.zeros(8), est_pose=np.array([t, 0.0, 0.0]),
                ref_pose=np.array([t, 0.001, 0.0]), true_pose=np.array([t, 0.0, 0.0]))


def _work(rng) -> None:
    a = rng.standard_normal((5, 5))
    for _ in range(20):                       # the law: a few 5x5 products and a solve
        b = a @ a.T / np.trace(a @ a.T) + np.eye(5)
        np.linalg.solve(b, np.ones(5))


def run(cycles: int, live: LivePublisher | None) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    cost, pub = [], []
    deadline = time.monotonic()
    for k in range(cycles):
        t0 = time.perf_counter()
        _work(rng)
        fields = _record(k)
        if live is not None:
            t1 = time.perf_counter()
            live.on_cycle(fields)
            pub.append(time.perf_counter() - t1)
        cost.append(time.perf_counter() - t0)
        deadline += PERIOD_S
        time.sleep(max(0.0, deadline - time.monotonic()))
    return np.array(cost), np.array(pub)


def _subscriber(url: str, stop: threading.Event, counts: dict) -> None:
    import websockets

    async def main():
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
            while not stop.is_set():
                try:
                    frame = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    continue
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg["op"] == "advertise":
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in msg["channels"]]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                else:
                    counts["messages"] = counts.get("messages", 0) + 1

    asyncio.run(main())


def _row(name: str, cost: np.ndarray, pub: np.ndarray, extra: str = "") -> str:
    us = cost * 1e6
    p = f"publish() p50 {np.median(pub) * 1e6:.1f} us, max {pub.max() * 1e6:.0f} us; " if pub.size else ""
    return (f"{name:<22} cycle p50 {np.median(us):6.0f} us  p99 {np.percentile(us, 99):6.0f} us  "
            f"max {us.max():6.0f} us; {p}{extra}")


def main(cycles: int = 1000) -> None:
    cost, pub = run(cycles, None)
    print(_row("no live view", cost, pub))
    with LivePublisher("127.0.0.1", 0) as live:
        cost, pub = run(cycles, live)
        print(_row("live, no client", cost, pub, f"dropped {live.dropped}"))
        stop, counts = threading.Event(), {}
        th = threading.Thread(target=_subscriber, args=(live.url, stop, counts), daemon=True)
        th.start()
        time.sleep(1.0)
        cost, pub = run(cycles, live)
        stop.set()
        th.join(5)
        print(_row("live, client", cost, pub, f"dropped {live.dropped}, client got {counts.get('messages', 0)} "
                                              f"messages, published {live.published} records"))


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def runs(scale: float) -> None:
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    for mode in ("no live view", "live, no client", "live, client"):
        port = _free_port()
        req = RunRequest(trajectory="line", emulate=True, time_scale=scale,
                         live=None if mode == "no live view" else f"127.0.0.1:{port}")
        stop, counts = threading.Event(), {}
        th = None
        if mode == "live, client":
            def keep_trying():
                while not stop.is_set():
                    try:
                        _subscriber(f"ws://127.0.0.1:{port}", stop, counts)
                    except OSError:                   # not up yet (or closed at the end)
                        time.sleep(0.1)
                    except Exception:  # noqa: BLE001 - websockets' ConnectionClosed at the end
                        return

            th = threading.Thread(target=keep_trying, daemon=True)
            th.start()
        s = run_tracking(req).summary
        stop.set()
        if th is not None:
            th.join(5)
        t = s.timing
        extra = "" if s.live is None else (f"; live published {s.live.live_published}, dropped "
                                           f"{s.live.live_dropped}, client got {counts.get('messages', 0)} messages")
        print(f"{mode:<16} period p50 {t.loop_period_p50_ms:.2f} p99 {t.loop_period_p99_ms:.2f} max "
              f"{t.loop_period_max_ms:.2f} ms (target {t.loop_period_target_ms:.2f}), overruns {t.overruns} "
              f"of {t.loop_cycles}, completed {s.completed}{extra}", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "run":
        runs(float(sys.argv[2]) if len(sys.argv) > 2 else 1.0)
    else:
        main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
