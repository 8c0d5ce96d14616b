#!/usr/bin/env python3
"""The SimpleCAN configuration signature of docs/simplecan.md section 11, computed from the
section's text alone (not from the tool's code), for the vectors of
tool/tests/simplecan_signature.rs.

CRC-32, polynomial 04C11DB7h, initial value FFFFFFFFh, not reflected, no final XOR, over:
the node-ID (1 octet); 5E00h sub-indices 01..05 (UNSIGNED16, 16, 16, 8, 8); 5E01h
(UNSIGNED8); per entry its sub-indices 01..06 (UNSIGNED8, 8, 16, 16, 32, 32); each value at
its type's size, least significant octet first.

Run: python3 tool/tests/vectors/simplecan_signature.py
"""


def crc32_mpeg2(data):
    # Polynomial division, one message bit at a time: the message (after the initial value
    # has been XORed into its first 32 bits) followed by 32 zero bits, divided by
    # x^32 + 04C11DB7h; the remainder is the CRC. Written as long division on a bit list,
    # deliberately unlike the tool's shift register.
    bits = []
    for octet in data:
        bits += [(octet >> (7 - i)) & 1 for i in range(8)]
    bits += [0] * 32
    for i in range(min(32, len(data) * 8)):
        bits[i] ^= 1  # the initial value FFFFFFFFh
    generator = [1] + [(0x04C11DB7 >> (31 - i)) & 1 for i in range(32)]
    for i in range(len(bits) - 32):
        if bits[i]:
            for j in range(33):
                bits[i + j] ^= generator[j]
    remainder = 0
    for bit in bits[-32:]:
        remainder = (remainder << 1) | bit
    return remainder


def le(value, size):
    return list(value.to_bytes(size, "little"))


def config_octets(node_id, n, k, buffering, enabled, master, entries):
    octets = [node_id] + le(n, 2) + le(k, 2) + le(buffering, 2) + [enabled, master]
    octets += [len(entries)]
    for sc_id, role, slot, timeout, node_hash, mapped in entries:
        octets += [sc_id, role] + le(slot, 2) + le(timeout, 2) + le(node_hash, 4) + le(mapped, 4)
    return octets


VECTORS = {
    "check": list(b"123456789"),
    # node 1: the potential master producing 30h in slot 0 from 6000h:01 (8 bits)
    "producer": config_octets(1, 10, 10, 500, 1, 1, [(0x30, 1, 0, 0, 0x12345678, 0x60000108)]),
    # node 33: consumes 30h (50 ms) and 41h (12 ms) into 6200h:01 and 6201h:01
    "consumer": config_octets(
        33, 10, 10, 500, 1, 0,
        [(0x30, 2, 0, 50, 0x12345678, 0x62000108), (0x41, 2, 0, 12, 0xA5C30F96, 0x62010108)],
    ),
    # node 7: SimpleCAN off, no entries
    "disabled": config_octets(7, 10, 10, 500, 0, 0, []),
    # node 2: produces 41h in slot 3, checks master 30h's syncs (role 3)
    "master_syncs": config_octets(
        2, 10, 10, 500, 1, 0,
        [(0x30, 3, 0, 0, 0x12345678, 0), (0x41, 1, 3, 0, 0xA5C30F96, 0x60010108)],
    ),
}

if __name__ == "__main__":
    for name, octets in VECTORS.items():
        print(f"{name}: {' '.join(f'{o:02X}' for o in octets)} -> {crc32_mpeg2(octets):08X}")
