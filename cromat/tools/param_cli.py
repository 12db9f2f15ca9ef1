"""``cromat param``: a running module's parameters over the MRI, as ``ros2 param`` does for a node.

    cromat param list ROBOT MODULE [--json]        every parameter: type, value, default, range, settable or not
    cromat param get ROBOT MODULE NAME [--json]
    cromat param set ROBOT MODULE NAME VALUE       typed and range-checked by the module's declaration

Exit codes: 0 done, 1 refused (the reason is printed; nothing changed), 2 usage, 3 no robot or no answer.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TextIO

import msgspec

from bbcs.contracts import mri
from bbcs.contracts.params import GetParam, ListParams, ParamInfo, ParamList, SetParam
from cromat.tools.connection import ToolError, add_connection_options, connect


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat param", description="list, get and set a running module's parameters "
                                "over the MRI (like ros2 param); only parameters the module declares settable at run "
                                "time can be set, the others are refused with the reason")
    add_connection_options(p)
    sub = p.add_subparsers(dest="command", required=True)
    for name, text in (("list", "every parameter of a module"), ("get", "one parameter"),
                       ("set", "set one parameter of the running module")):
        c = sub.add_parser(name, help=text)
        c.add_argument("robot")
        c.add_argument("module")
        if name != "list":
            c.add_argument("name")
        if name == "set":
            c.add_argument("value", help="written as in the manifest's params (a string the type converts)")
        else:
            c.add_argument("--json", action="store_true", help="the parameters as JSON")
    return p


def _value(v: object) -> str:
    return "-" if v is None else json.dumps(v) if not isinstance(v, str) else v


def table(params: list[ParamInfo]) -> list[str]:
    """One row per parameter; the reason a parameter is not settable follows the table once per reason."""
    rows = [("name", "type", "value", "default", "range", "at run time")]
    for p in params:
        limits = p.range or (", ".join(p.choices) if p.choices else "")
        rows.append((p.name, p.type, _value(p.value), _value(p.default), limits or "-",
                     "settable" if p.settable else "start-up only"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]


def _print(data: ParamList, as_json: bool, out: TextIO) -> None:
    if as_json:
        print(json.dumps(msgspec.to_builtins(data), indent=2), file=out)
        return
    for line in table(data.params):
        print(line, file=out)
    for why in dict.fromkeys(p.why for p in data.params if p.why and not p.settable):
        if not data.declared or len(data.params) == 1:
            print(f"({why})", file=out)
    if data.declared and len(data.params) > 1 and any(not p.settable for p in data.params):
        print(f"(start-up only: read when {data.module} starts; change the manifest and restart it)", file=out)


def run(args: argparse.Namespace, out: TextIO) -> int:
    session = connect(args)
    try:
        if args.command == "list":
            reply = mri.call(session, args.robot, "param", ListParams(module=args.module), args.timeout)
        elif args.command == "get":
            reply = mri.call(session, args.robot, "param", GetParam(module=args.module, name=args.name),
                             args.timeout)
        else:
            reply = mri.call(session, args.robot, "param",
                             SetParam(module=args.module, name=args.name, value=args.value),
                             max(args.timeout, mri.REPLY_TIMEOUT_S))
    except mri.MriError as exc:
        raise ToolError(str(exc), 3) from None
    finally:
        session.close()
    if not reply.ok:
        print(f"cromat param {args.command}: refused: {reply.reason}", file=sys.stderr)
        return 1
    assert isinstance(reply.data, ParamList)
    if args.command == "set":
        got = reply.data.params[0]
        print(f"{args.robot}/{reply.data.module}.{got.name} = {_value(got.value)}", file=out)
        return 0
    _print(reply.data, args.json, out)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args, sys.stdout)
    except ToolError as exc:
        print(f"cromat param: {exc}", file=sys.stderr)
        return exc.code


if __name__ == "__main__":
    raise SystemExit(main())
