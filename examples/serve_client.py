#!/usr/bin/env python3
"""Streams a readings log (CSV t,x,y,value) to `plumenet serve --listen HOST:PORT` in chunks,
asks for an iteration after each chunk and prints the goals. Standard library only.

    plumenet serve --solver --listen 127.0.0.1:7878 &
    python3 examples/serve_client.py 127.0.0.1:7878 log.csv --chunk 200
"""

import argparse
import csv
import json
import socket


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("address", help="HOST:PORT of plumenet serve")
    ap.add_argument("log", help="CSV with the columns t,x,y,value")
    ap.add_argument("--chunk", type=int, default=200, help="readings per request")
    args = ap.parse_args()

    host, port = args.address.rsplit(":", 1)
    with open(args.log, newline="") as f:
        readings = [
            {k: float(row[k]) for k in ("t", "x", "y", "value")} for row in csv.DictReader(f)
        ]

    with socket.create_connection((host, int(port))) as sock:
        stream = sock.makefile("rw", encoding="utf-8", newline="\n")
        next_id = 0

        def call(op, **fields):
            nonlocal next_id
            next_id += 1
            stream.write(json.dumps({"id": next_id, "op": op, **fields}) + "\n")
            stream.flush()
            reply = json.loads(stream.readline())
            if not reply["ok"]:
                raise SystemExit(f"request {next_id} ({op}) refused: {reply['error']}")
            return reply

        hello = call("hello")
        print(f"session: {hello['layout']}, model {hello['model']}, {hello['candidates']} candidates")
        for start in range(0, len(readings), args.chunk):
            accepted = call("readings", readings=readings[start : start + args.chunk])["accepted"]
            it = call("iterate")
            goal = "none (done)" if it["goal"] is None else f"({it['goal'][0]:.2f}, {it['goal'][1]:.2f})"
            print(
                f"{accepted:6d} readings  estimate ({it['estimate'][0]:.2f}, {it['estimate'][1]:.2f})"
                f"  entropy {it['entropy']:.2f}  converged {it['converged']}  next goal {goal}"
            )


if __name__ == "__main__":
    main()
