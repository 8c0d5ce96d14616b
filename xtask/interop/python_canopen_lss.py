"""python-canopen's LSS master against unconfigured LSS nodes behind socketcand
(`cargo xtask interop --only lss`, `--only lss-bench`).

Usage: python_canopen_lss.py HOST PORT OFFSET TIMEOUT_S STORE CHECK [BIT_TIMING]

Until `LssMaster.fast_scan` finds no node: fast scan (CiA 305 Fig. 46), configure node-ID
(serial number + OFFSET), with BIT_TIMING configure bit timing to 800 kbit/s (which the
device refuses: `refused_800` holds python-canopen's error) and then to that index of CiA
301's table (Fig. 34), store configuration when STORE is 1, with BIT_TIMING activate bit timing
(Fig. 35) with a switch delay of SWITCH_DELAY_MS and wait twice that (the bus switches with
the node), switch state global waiting (the node takes its node-ID and boots). `LssMaster.RESPONSE_TIMEOUT` is TIMEOUT_S. Then one
more switch state global waiting marks the end on the bus. With CHECK 1, afterwards: each node
configured is read its identity (1018h) by SDO at its new node-ID, and reset (NMT reset node)
to see it boot on the node-ID again.

A second connection records every frame with the server's time stamp (the simulated bus's
time). Prints one JSON line: the identities found with their node-IDs, the recorded frames,
the stamps of the first LSS request and of the end mark, and what the check read.
"""

import json
import sys
import threading
import time

import can
import canopen
from canopen.lss import LssMaster

WAITING_STATE = LssMaster.WAITING_STATE

# The switch delay of activate bit timing: the node is silent for twice this around the switch.
SWITCH_DELAY_MS = 100


def main() -> int:
    host, port, offset, timeout, store, check = sys.argv[1:7]
    port, offset, timeout = int(port), int(offset), float(timeout)
    store, check = store == "1", check == "1"
    bit_timing = int(sys.argv[7]) if len(sys.argv) > 7 else None

    recorder = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    recorded = []
    stop = threading.Event()

    def record():
        while not stop.is_set():
            message = recorder.recv(timeout=0.2)
            if message is not None:
                recorded.append(
                    (message.timestamp, message.arbitration_id, bytes(message.data).hex())
                )

    thread = threading.Thread(target=record)
    thread.start()
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=port, channel="can0")
    result = {"found": [], "failures": []}
    try:
        # Both connections joined before the first request.
        time.sleep(0.5)
        network.lss.RESPONSE_TIMEOUT = timeout
        while True:
            found, identity = network.lss.fast_scan()
            if not found:
                break
            node_id = identity[3] + offset
            network.lss.configure_node_id(node_id)
            if bit_timing is not None:
                # 800 kbit/s first: a rate the device cannot make (CiA 305 error code 1).
                try:
                    network.lss.configure_bit_timing(1)
                    result["refused_800"] = False
                except canopen.lss.LssError as error:
                    result["refused_800"] = str(error)
                network.lss.configure_bit_timing(bit_timing)
            if store:
                network.lss.store_configuration()
            if bit_timing is not None:
                network.lss.activate_bit_timing(SWITCH_DELAY_MS)
                time.sleep(2 * SWITCH_DELAY_MS / 1000 + 0.05)
            network.lss.send_switch_state_global(WAITING_STATE)
            result["found"].append({"identity": identity, "node_id": node_id})
        network.lss.send_switch_state_global(WAITING_STATE)
        time.sleep(0.3)
        result["bit_timing"] = bit_timing
        if check:
            result["checked"] = []
            for entry in result["found"]:
                node = network.add_node(entry["node_id"], canopen.ObjectDictionary())
                node.sdo.RESPONSE_TIMEOUT = 2.0
                try:
                    read = [
                        int.from_bytes(node.sdo.upload(0x1018, sub), "little")
                        for sub in range(1, 5)
                    ]
                except Exception as error:  # noqa: BLE001 - reported, not hidden
                    result["failures"].append(f"node {entry['node_id']}: 1018h: {error}")
                    read = None
                node.nmt.send_command(0x81)
                time.sleep(0.3)
                result["checked"].append({"node_id": entry["node_id"], "identity": read})
    finally:
        stop.set()
        thread.join()
        network.disconnect()
        recorder.shutdown()
    requests = [entry for entry in recorded if entry[1] == 0x7E5]
    result["frames"] = recorded
    result["first_request"] = requests[0][0] if requests else None
    # The end mark: the switch state global that followed the last fast scan.
    marks = [
        entry[0] for entry in requests if entry[2].startswith("0400")
    ]
    result["end"] = marks[-1] if marks else None
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
