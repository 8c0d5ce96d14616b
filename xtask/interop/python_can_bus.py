"""python-can's own socketcand bus on the hub's tool port (`cargo xtask interop`).

Usage: python_can_bus.py HOST PORT COUNT

Connects with python-can's `socketcand` interface (which checks each handshake reply by one
recv and exact equality), prints `ready`, receives COUNT frames, answers each one on its
identifier + 1 with its data reversed, then prints what it received as one JSON line.
"""

import json
import sys

import can


def main() -> int:
    host, port, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    print("ready", flush=True)
    received = []
    try:
        while len(received) < count:
            message = bus.recv(timeout=10.0)
            if message is None:
                break
            received.append(
                {
                    "id": message.arbitration_id,
                    "extended": message.is_extended_id,
                    "data": list(message.data),
                }
            )
        for frame in received:
            bus.send(
                can.Message(
                    arbitration_id=frame["id"] + 1,
                    is_extended_id=False,
                    data=bytes(reversed(frame["data"])),
                )
            )
        print(json.dumps({"received": received}), flush=True)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
