"""The floor of any Python checker of a JSON Lines trace (bench/check_jsonl.py): a process
that only scans every line with msgspec's decoder (the fastest JSON reader edgerv found;
its messages left undecoded, as msgspec.Raw) and counts the lines, checking nothing.
Its whole-process time bounds what `edgerv check` (or any Python tool) can reach on the
file: the interpreter's start plus one pass of the fastest scanner."""

import sys

import msgspec


class Record(msgspec.Struct):
    topic: str
    stamp: int
    msg: msgspec.Raw


decoder, lines = msgspec.json.Decoder(Record), 0
with open(sys.argv[1], "rb") as f:
    while block := f.read(1 << 17):
        lines += len(decoder.decode_lines(block + f.readline()))
print(lines)
