"""python-canopen doing the configuration tool's job (`cargo xtask interop --only bench`):
the same SDO writes and read-backs as `safety-config configure` and `verify`
(EN 50325-5 8.3.1), timed, so the two can be compared on the same emulated bus.

Usage: python_canopen_configure.py HOST PORT EDS SPEC

SPEC is JSON: {"nodes": [{"id", "srdos": [{"number", "direction", "cycle_time", "srvt",
"cob_id_1", "cob_id_2", "mapping"}]}]}. The nodes are configured one after another, then
verified one after another (python-canopen's SDO client waits for each answer; the script
runs no thread per node). For each node, in the tool's order: identity (1018h), NMT
pre-operational, the
SRDO count (13FFh:00h), every SRDO deleted (direction 0), mappings, communication
parameters, every record read back in the reverse order and compared, the signatures
(EN 50325-5 Table 9, CRC-16/XMODEM: Python's `binascii.crc_hqx` with seed 0) written to
13FFh and read back, 13FEh = A5h and read, 1010h:01h = "save", 13FEh read again; then the
verification: identity, 13FEh, every record and signature read and the signatures
recomputed. Every transfer is python-canopen's SDO client (`upload`/`download`, expedited).

Prints one JSON line: the seconds each part took (all nodes), the SDO transactions (all
nodes), the signatures per node; exits 1 with a sentence when anything read back differs.
"""

import binascii
import json
import struct
import sys
import time

import canopen


class Counted:
    """python-canopen's SDO client, counting transfers."""

    def __init__(self, sdo):
        self.sdo = sdo
        self.transactions = 0

    def read(self, index, sub, size):
        self.transactions += 1
        data = self.sdo.upload(index, sub)
        return int.from_bytes(data[:size], "little")

    def write(self, index, sub, value, size):
        self.transactions += 1
        self.sdo.download(index, sub, value.to_bytes(size, "little"))

    def write_bytes(self, index, sub, data):
        self.transactions += 1
        self.sdo.download(index, sub, data)


def record(sdo, n):
    """SRDO n's record, read in the tool's order (COB-IDs first, the mapping last)."""
    comm, mapping = 0x1300 + n, 0x1380 + n
    cob_id_2 = sdo.read(comm, 6, 4)
    cob_id_1 = sdo.read(comm, 5, 4)
    sdo.read(comm, 4, 1)
    srvt = sdo.read(comm, 3, 1)
    cycle_time = sdo.read(comm, 2, 2)
    direction = sdo.read(comm, 1, 1)
    count = min(sdo.read(mapping, 0, 1), 16)
    entries = [sdo.read(mapping, sub, 4) for sub in range(1, count + 1)]
    return {
        "number": n,
        "direction": direction,
        "cycle_time": cycle_time,
        "srvt": srvt,
        "cob_id_1": cob_id_1,
        "cob_id_2": cob_id_2,
        "mapping": entries,
    }


def signature(srdo):
    """EN 50325-5 Table 9: the octets, then CRC-16/XMODEM (polynomial 1021h, seed 0)."""
    octets = struct.pack(
        "<BHBIIB",
        srdo["direction"],
        srdo["cycle_time"],
        srdo["srvt"],
        srdo["cob_id_1"],
        srdo["cob_id_2"],
        len(srdo["mapping"]),
    )
    for sub, entry in enumerate(srdo["mapping"], start=1):
        octets += struct.pack("<BI", sub, entry)
    return binascii.crc_hqx(octets, 0)


def fail(message):
    print(json.dumps({"error": message}))
    sys.exit(1)


def configure(node, sdo, wanted):
    """The configuration of one node, in the tool's order; returns its identity and signatures."""
    node_id = node.id
    identity = [sdo.read(0x1018, sub, 4) for sub in range(1, 5)]
    node.nmt.state = "PRE-OPERATIONAL"
    count = sdo.read(0x13FF, 0, 1)
    for n in range(1, count + 1):
        sdo.write(0x1300 + n, 1, 0, 1)
    for n, srdo in sorted(wanted.items()):
        mapping = 0x1380 + n
        sdo.write(mapping, 0, 0, 1)
        for sub, entry in enumerate(srdo["mapping"], start=1):
            sdo.write(mapping, sub, entry, 4)
        sdo.write(mapping, 0, len(srdo["mapping"]), 1)
    for n, srdo in sorted(wanted.items()):
        comm = 0x1300 + n
        sdo.write(comm, 2, srdo["cycle_time"], 2)
        sdo.write(comm, 3, srdo["srvt"], 1)
        sdo.write(comm, 5, srdo["cob_id_1"], 4)
        sdo.write(comm, 6, srdo["cob_id_2"], 4)
        sdo.write(comm, 1, srdo["direction"], 1)
    signatures = {}
    for n in range(count, 0, -1):
        held = record(sdo, n)
        if n in wanted and held != wanted[n]:
            fail(f"node {node_id} SRDO {n} reads back {held}, not {wanted[n]}")
        signatures[n] = signature(wanted.get(n, held))
    for n in range(1, count + 1):
        sdo.write(0x13FF, n, signatures[n], 2)
    for n in range(count, 0, -1):
        if sdo.read(0x13FF, n, 2) != signatures[n]:
            fail(f"node {node_id}: the signature of SRDO {n} does not read back")
    sdo.write(0x13FE, 0, 0xA5, 1)
    if sdo.read(0x13FE, 0, 1) != 0xA5:
        fail(f"node {node_id}: 0x13FE does not read A5h after writing it")
    sdo.write_bytes(0x1010, 1, b"save")
    if sdo.read(0x13FE, 0, 1) != 0xA5:
        fail(f"node {node_id}: 0x13FE does not read A5h after storing")
    return identity, count, signatures


def verify(node_id, sdo, wanted, identity, count):
    """The verification of one node: identity, 13FEh, every record and signature."""
    if [sdo.read(0x1018, sub, 4) for sub in range(1, 5)] != identity:
        fail(f"node {node_id}: the identity changed")
    if sdo.read(0x13FE, 0, 1) != 0xA5:
        fail(f"node {node_id}: not validated")
    for n in range(1, count + 1):
        held = record(sdo, n)
        if sdo.read(0x13FF, n, 2) != signature(held):
            fail(f"node {node_id}: the signature of SRDO {n} does not match its record")
        if n in wanted and held != wanted[n]:
            fail(f"node {node_id} SRDO {n} holds {held}, not {wanted[n]}")


def main() -> int:
    host, port, eds, spec = sys.argv[1:5]
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=int(port), channel="can0")
    try:
        nodes = []
        for entry in json.loads(spec)["nodes"]:
            node = canopen.RemoteNode(entry["id"], canopen.import_od(eds, entry["id"]))
            network.add_node(node)
            node.sdo.RESPONSE_TIMEOUT = 2.0
            wanted = {srdo["number"]: srdo for srdo in entry["srdos"]}
            nodes.append((node, Counted(node.sdo), wanted))

        started = time.perf_counter()
        configured_nodes = [
            configure(node, sdo, wanted) for node, sdo, wanted in nodes
        ]
        configured = time.perf_counter()
        configure_transactions = sum(sdo.transactions for _, sdo, _ in nodes)

        for (node, sdo, wanted), (identity, count, _) in zip(nodes, configured_nodes):
            verify(node.id, sdo, wanted, identity, count)
        verified = time.perf_counter()
        transactions = sum(sdo.transactions for _, sdo, _ in nodes)

        print(
            json.dumps(
                {
                    "configure_s": configured - started,
                    "verify_s": verified - configured,
                    "configure_transactions": configure_transactions,
                    "verify_transactions": transactions - configure_transactions,
                    "signatures": {
                        str(node.id): {str(n): value for n, value in signed.items()}
                        for (node, _, _), (_, _, signed) in zip(nodes, configured_nodes)
                    },
                }
            )
        )
    finally:
        network.disconnect()
    return 0


if __name__ == "__main__":
    sys.exit(main())
