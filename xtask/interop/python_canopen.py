"""python-canopen on the emulated network through the hub's socketcand port
(`cargo xtask interop`).

Usage: python_canopen.py HOST PORT EDS NODE PHASE

Loads the node's EDS with `canopen.import_od`, then, by PHASE:

- `operational`: reads the identity (1018h) and every SRDO's configuration (1301h.., 1381h..,
  13FFh, 13FEh) and tries to write an SRDO's SRVT (1301h:03h) with the value it holds;
- `pre-operational`: writes SCT 0 to 1301h:02h (out of range), then the SCT it holds (valid),
  and reads 13FEh.

Prints one JSON line: the values read, and each write's abort code (null when accepted).
"""

import json
import sys

import canopen


def write(variable, value):
    """The abort code of writing `value`, or None when the node accepted it."""
    try:
        variable.raw = value
        return None
    except canopen.SdoAbortedError as error:
        return error.code


def main() -> int:
    host, port, eds, node_id, phase = sys.argv[1:6]
    node_id = int(node_id)
    od = canopen.import_od(eds, node_id)
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=int(port), channel="can0")
    try:
        node = canopen.RemoteNode(node_id, od)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        result = {"phase": phase}
        if phase == "operational":
            result["identity"] = [node.sdo[0x1018][sub].raw for sub in range(1, 5)]
            srdos = []
            count = node.sdo[0x13FF][0].raw
            for n in range(1, count + 1):
                comm = node.sdo[0x1300 + n]
                mapping = node.sdo[0x1380 + n]
                entries = mapping[0].raw
                srdos.append(
                    {
                        "direction": comm[1].raw,
                        "cycle_time": comm[2].raw,
                        "srvt": comm[3].raw,
                        "transmission_type": comm[4].raw,
                        "cob_id_1": comm[5].raw,
                        "cob_id_2": comm[6].raw,
                        "mapping": [mapping[sub].raw for sub in range(1, entries + 1)],
                        "signature": node.sdo[0x13FF][n].raw,
                    }
                )
            result["srdos"] = srdos
            result["configuration_valid"] = node.sdo[0x13FE].raw
            srvt = node.sdo[0x1301][3]
            result["operational_write_abort"] = write(srvt, srvt.raw)
        elif phase == "pre-operational":
            sct = node.sdo[0x1301][2]
            held = sct.raw
            result["out_of_range_abort"] = write(sct, 0)
            result["valid_write_abort"] = write(sct, held)
            result["configuration_valid"] = node.sdo[0x13FE].raw
        else:
            raise SystemExit(f"unknown phase {phase!r}")
        print(json.dumps(result), flush=True)
    finally:
        network.disconnect()
    return 0


if __name__ == "__main__":
    sys.exit(main())
