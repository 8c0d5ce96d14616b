"""python-can and python-canopen on the shipped images' emulated network, through
`emulate-network --socketcand` (`cargo xtask interop --only emulated-network`).

Usage: python_emulated_network.py HOST PORT EDS SECONDS

1. python-can's `socketcand` bus listens for SECONDS (wall clock) and reports every
   heartbeat it received (CiA 301 7.2.8.3.2: identifier 700h + node-ID, one byte of NMT
   state) with the server's time stamp;
2. python-canopen loads the node's EDS and reads node 1's identity (1018h:01h..04h) and its
   producer heartbeat time (1017h) by SDO.

Prints one JSON line.
"""

import json
import sys
import time

import can
import canopen


def heartbeats(host: str, port: int, seconds: float) -> dict:
    """Every heartbeat python-can received within `seconds`, by node-ID: (stamp, state)."""
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    seen: dict = {}
    frames = 0
    try:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            message = bus.recv(timeout=left)
            if message is None:
                break
            frames += 1
            node = message.arbitration_id - 0x700
            if 1 <= node <= 127 and len(message.data) == 1 and not message.is_remote_frame:
                seen.setdefault(str(node), []).append(
                    [round(message.timestamp, 6), message.data[0]]
                )
    finally:
        bus.shutdown()
    return {"frames": frames, "heartbeats": seen}


def identity(host: str, port: int, eds: str, node_id: int) -> dict:
    """Node `node_id`'s 1018h:01h..04h and 1017h, read by python-canopen's SDO client."""
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=port, channel="can0")
    try:
        node = canopen.RemoteNode(node_id, canopen.import_od(eds, node_id))
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        started = time.monotonic()
        values = [node.sdo[0x1018][sub].raw for sub in range(1, 5)]
        heartbeat_time = node.sdo[0x1017].raw
        return {
            "identity": values,
            "heartbeat_time_ms": heartbeat_time,
            "sdo_seconds": round(time.monotonic() - started, 4),
        }
    finally:
        network.disconnect()


def main() -> int:
    host, port, eds, seconds = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
    result = heartbeats(host, port, seconds)
    result["node1"] = identity(host, port, eds, 1)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
