"""Every object of the node's EDS, through python-canopen, checked against the EDS itself
(`cargo xtask interop`): what a CANopen conformance test (CiA 310 style) or a user with
python-canopen does first with a new device. Nothing here knows our implementation: the
expectations come from the EDS (data types, access types) and from CiA 301 7.2.4.3.17
(the SDO abort codes).

Usage: python_canopen_sweep.py HOST PORT EDS NODE

Switches the node to Pre-operational (NMT), then for every entry of the EDS:

- readable entries (ro, const, rw, rwr, rww) upload, and a fixed-size type uploads as many
  bytes as the type has;
- `const` and `ro` entries refuse a download of the value they hold with 0601 0002h
  (attempt to write a read-only object); `wo` entries refuse an upload with 0601 0001h;
- writable entries of a fixed size of 2 or 4 bytes refuse a download one byte too long and
  one byte too short with 0607 0010h, 0607 0012h or 0607 0013h (data type length);
- a record's or array's highest sub-index plus one, when the EDS has no such entry, is
  refused with 0609 0011h (sub-index does not exist); an index the EDS does not list with
  0602 0000h (object does not exist);

and at the end reads 13FEh: no refused write may have touched the validated configuration
(A5h before and after). Then NMT start.

Prints one JSON line: how many entries were checked, and every deviation found (an empty
list when the node answers as its EDS says).
"""

import json
import sys

import canopen
from canopen.objectdictionary import datatypes

# Sizes in bytes of the fixed-size CiA 301 data types.
SIZES = {
    datatypes.BOOLEAN: 1,
    datatypes.INTEGER8: 1,
    datatypes.INTEGER16: 2,
    datatypes.INTEGER32: 4,
    datatypes.UNSIGNED8: 1,
    datatypes.UNSIGNED16: 2,
    datatypes.UNSIGNED32: 4,
    datatypes.REAL32: 4,
    datatypes.INTEGER64: 8,
    datatypes.UNSIGNED64: 8,
    datatypes.REAL64: 8,
}
READ_ONLY = 0x0601_0002
WRITE_ONLY = 0x0601_0001
NO_OBJECT = 0x0602_0000
NO_SUB_INDEX = 0x0609_0011
LENGTH = {0x0607_0010, 0x0607_0012, 0x0607_0013}


def abort_of(call):
    """The abort code `call` ended with, None when the node accepted it."""
    try:
        call()
        return None
    except canopen.SdoAbortedError as error:
        return error.code


def entries(od):
    """Every variable of the dictionary, with the record or array it belongs to (or None)."""
    for obj in od.values():
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            yield obj, None
        else:
            for var in obj.values():
                yield var, obj


def main() -> int:
    host, port, eds, node_id = sys.argv[1:5]
    node_id = int(node_id)
    od = canopen.import_od(eds, node_id)
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=int(port), channel="can0")
    deviations = []
    checked = 0

    def deviation(var, text):
        deviations.append(f"{var.index:04X}h:{var.subindex:02X}h ({var.name}): {text}")

    try:
        node = canopen.RemoteNode(node_id, od)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        sdo = node.sdo
        valid_before = sdo.upload(0x13FE, 0)
        node.nmt.send_command(0x80)  # Enter Pre-operational
        network.check()
        import time

        time.sleep(0.3)
        for var, parent in entries(od):
            checked += 1
            index, sub = var.index, var.subindex
            access = var.access_type
            size = SIZES.get(var.data_type)
            held = None
            if access in ("ro", "const", "rw", "rwr", "rww"):
                try:
                    held = sdo.upload(index, sub)
                except canopen.SdoAbortedError as error:
                    deviation(var, f"upload aborted with {error.code:08X}h ({access})")
                    continue
                if size is not None and len(held) != size:
                    deviation(var, f"uploads {len(held)} bytes, its type has {size}")
            if access in ("ro", "const") and held is not None:
                code = abort_of(lambda: sdo.download(index, sub, held))
                if code != READ_ONLY:
                    shown = "accepted" if code is None else f"{code:08X}h"
                    deviation(var, f"download to a {access} entry: {shown}, not {READ_ONLY:08X}h")
            if access == "wo":
                code = abort_of(lambda: sdo.upload(index, sub))
                if code != WRITE_ONLY:
                    shown = "accepted" if code is None else f"{code:08X}h"
                    deviation(var, f"upload of a wo entry: {shown}, not {WRITE_ONLY:08X}h")
            if access in ("rw", "rwr", "rww", "wo") and size in (2, 4):
                for wrong in (size + 1, size - 1):
                    code = abort_of(lambda: sdo.download(index, sub, bytes(wrong)))
                    if code not in LENGTH:
                        shown = "accepted" if code is None else f"{code:08X}h"
                        deviation(
                            var,
                            f"download of {wrong} bytes to a {size}-byte entry: {shown}, "
                            "not a length abort (0607 0010h/0012h/0013h)",
                        )
        for obj in od.values():
            if isinstance(obj, canopen.objectdictionary.ODVariable):
                continue
            beyond = max(var.subindex for var in obj.values()) + 1
            if beyond <= 0xFF and beyond not in obj:
                checked += 1
                code = abort_of(lambda: sdo.upload(obj.index, beyond))
                if code != NO_SUB_INDEX:
                    shown = "accepted" if code is None else f"{code:08X}h"
                    deviations.append(
                        f"{obj.index:04X}h:{beyond:02X}h (beyond {obj.name}): {shown}, "
                        f"not {NO_SUB_INDEX:08X}h"
                    )
        missing = next(i for i in range(0x2000, 0x6000) if i not in od)
        checked += 1
        code = abort_of(lambda: sdo.upload(missing, 0))
        if code != NO_OBJECT:
            shown = "accepted" if code is None else f"{code:08X}h"
            deviations.append(f"{missing:04X}h (not in the EDS): {shown}, not {NO_OBJECT:08X}h")
        valid_after = sdo.upload(0x13FE, 0)
        if valid_after != valid_before:
            deviations.append(
                f"13FEh read {valid_before.hex()} before the sweep and {valid_after.hex()} after: "
                "a refused write changed the configuration"
            )
        node.nmt.send_command(0x01)  # Start
        print(
            json.dumps({"checked": checked, "valid": valid_after.hex(), "deviations": deviations}),
            flush=True,
        )
    finally:
        network.disconnect()
    return 0


if __name__ == "__main__":
    sys.exit(main())
