"""python-canopen reading a node's objects back to back while python-can loads the bus
(`cargo xtask interop --only mixed-load`).

Usage: mixed_load.py HOST PORT NODE SECONDS PERCENT

Three connections to the hub's socketcand port:

- a python-can bus that sends ordinary frames (a fifth of them on low identifiers, 010h to
  02Eh, above every frame of the nodes; the rest on 281h to 4FFh; 8 data bytes) so that they
  fill PERCENT of a 500 kbit/s bus (stuff bits not counted), in bus time (the hub's time
  stamps, which follow the emulated network's virtual time, not the host's);
- a python-can bus that records every frame with the hub's timestamp;
- python-canopen, reading NODE's identity and SRDO configuration one upload after the other
  with its own response time-out (host time), counting time-outs and replies that answered
  another request than the one it waited for.

Runs until SECONDS of bus time have passed since the first frame recorded, then prints one
JSON line: from the recorded frames (bus time), every SDO request's response time (an answer
paired with the request for its object), each node's heartbeat gaps, the load's share of the
bus and the longest stretch of frames back to back; from python-canopen (host time), the
uploads, time-outs and wrong replies.
"""

import json
import random
import sys
import threading
import time

import can
import canopen

BIT_RATE = 500_000
# The most frames the load sends at once to catch up with its share.
BURST_FRAMES = 4


def frame_bits(data_length: int) -> int:
    """Bits of a standard data frame without stuff bits, plus the intermission (a lower
    bound: stuff bits add up to a fifth)."""
    return 47 + 8 * data_length


def main() -> int:
    host, port, node_id, seconds, percent = sys.argv[1:6]
    port, node_id, seconds, percent = int(port), int(node_id), float(seconds), float(percent)
    stop = threading.Event()
    recorded = []
    first = [None]
    latest = [None]

    recorder = can.Bus(interface="socketcand", host=host, port=port, channel="can0")

    def record():
        while not stop.is_set():
            message = recorder.recv(timeout=0.5)
            if message is None:
                continue
            recorded.append((message.timestamp, message.arbitration_id, bytes(message.data)))
            if first[0] is None:
                first[0] = message.timestamp
            latest[0] = message.timestamp
            if latest[0] - first[0] >= seconds:
                stop.set()

    loader = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    sent_bits = [0]
    rng = random.Random(1)

    def load():
        # Frames on 010h..02Eh (a fifth) and 281h..4FFh, paced in bus time. The budget grows
        # with the bus time; what this script could not send while it was not scheduled is
        # not made up for beyond a few frames, so the load stays near its share rather than
        # filling the bus in bursts once the script runs again.
        while not stop.is_set():
            if first[0] is None or latest[0] is None:
                time.sleep(0.01)
                continue
            budget = (latest[0] - first[0] + 0.02) * BIT_RATE * percent / 100.0
            sent_bits[0] = max(sent_bits[0], budget - BURST_FRAMES * frame_bits(8))
            if sent_bits[0] >= budget:
                time.sleep(0.002)
                continue
            if rng.random() < 0.2:
                identifier = rng.randrange(0x010, 0x02F)
            else:
                identifier = rng.randrange(0x281, 0x500)
            data = bytes(rng.randrange(256) for _ in range(8))
            loader.send(can.Message(arbitration_id=identifier, is_extended_id=False, data=data))
            sent_bits[0] += frame_bits(8)

    threads = [threading.Thread(target=record, daemon=True), threading.Thread(target=load, daemon=True)]
    for thread in threads:
        thread.start()

    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=port, channel="can0")
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    network.add_node(node)
    timeout = node.sdo.RESPONSE_TIMEOUT
    objects = [(0x1018, sub) for sub in range(1, 5)]
    objects += [(0x1301, sub) for sub in range(1, 7)] + [(0x1381, sub) for sub in range(0, 3)]
    objects += [(0x13FF, sub) for sub in range(0, 5)] + [(0x13FE, 0)]
    uploads = timeouts = wrong = 0
    longest_host = 0.0
    failures = []
    try:
        while not stop.is_set():
            for index, sub in objects:
                if stop.is_set():
                    break
                started = time.monotonic()
                try:
                    node.sdo.upload(index, sub)
                    uploads += 1
                except canopen.SdoCommunicationError as error:
                    text = str(error)
                    if "timeout" in text.lower() or "no sdo response" in text.lower():
                        timeouts += 1
                    else:
                        wrong += 1
                    if len(failures) < 20:
                        failures.append(f"{index:04X}h:{sub:02X}h: {text}")
                except canopen.SdoAbortedError as error:
                    if len(failures) < 20:
                        failures.append(f"{index:04X}h:{sub:02X}h: abort {error.code:08X}h")
                longest_host = max(longest_host, time.monotonic() - started)
    finally:
        stop.set()
        network.disconnect()
        for thread in threads:
            thread.join(timeout=2)
        loader.shutdown()
        recorder.shutdown()

    request_id, response_id = 0x600 + node_id, 0x580 + node_id
    responses = []
    requests = 0
    # Requests waiting for their answer, by object (index and sub-index, CiA 301 7.2.4.3):
    # an answer that comes after the client gave up still answers its own request.
    waiting = {}
    heartbeats = {}
    load_bits = 0
    total_bits = 0
    busy_since = None
    previous_end = None
    longest_busy = 0.0
    for stamp, identifier, data in recorded:
        bits = frame_bits(len(data))
        total_bits += bits
        # Back to back: this frame began when the one before it ended (stuff bits allowed).
        duration = bits / BIT_RATE
        if previous_end is not None and stamp - previous_end <= duration * 1.25:
            longest_busy = max(longest_busy, stamp - busy_since)
        else:
            busy_since = stamp - duration
        previous_end = stamp
        if 0x010 <= identifier < 0x02F or 0x281 <= identifier < 0x500:
            load_bits += bits
        # A client's abort (command specifier 4, CiA 301 7.2.4.3.17) is answered by nothing.
        if identifier == request_id and data[:1] != b"\x80":
            requests += 1
            waiting.setdefault(bytes(data[1:4]), []).append(stamp)
        elif identifier == response_id and waiting.get(bytes(data[1:4])):
            responses.append(stamp - waiting[bytes(data[1:4])].pop(0))
        elif 0x701 <= identifier <= 0x77F:
            heartbeats.setdefault(identifier - 0x700, []).append(stamp)
    end = recorded[-1][0] if recorded else 0.0
    # Requests sent in the last second the recording did not see answered yet: not counted.
    requests -= sum(1 for stamps in waiting.values() for at in stamps if end - at < 1.0)
    span = (recorded[-1][0] - recorded[0][0]) if len(recorded) > 1 else 0.0
    gaps = {
        str(node): max((b - a for a, b in zip(stamps, stamps[1:])), default=0.0)
        for node, stamps in heartbeats.items()
    }
    worst = sorted(responses)[-5:] if responses else []
    print(
        json.dumps(
            {
                "bus_seconds": span,
                "frames": len(recorded),
                "load_share": load_bits / (span * BIT_RATE) if span else 0.0,
                "bus_share": total_bits / (span * BIT_RATE) if span else 0.0,
                "sdo_requests": requests,
                "sdo_responses": len(responses),
                "sdo_response_max_ms": 1000 * max(responses, default=0.0),
                "sdo_response_worst_ms": [1000 * r for r in worst],
                "longest_busy_ms": 1000 * longest_busy,
                "heartbeat_gap_max_ms": {node: 1000 * gap for node, gap in gaps.items()},
                "uploads": uploads,
                "timeouts": timeouts,
                "wrong_replies": wrong,
                "client_timeout_s": timeout,
                "longest_upload_host_s": longest_host,
                "failures": failures,
            }
        ),
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
