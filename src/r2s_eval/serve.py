"""Serve a policy over the openpi websocket protocol.

    python -m r2s_eval.serve PATH [--host 127.0.0.1] [--port 8000] [--device cpu] [--name NAME]
                                  [--api-key-env ENVVAR] [--debug]

PATH is a LeRobot `pretrained_model` folder or a training output folder holding one. Prints
`serving <name> on ws://host:port` once it accepts connections. The API key, when wanted, is
read from the environment variable named by --api-key-env (a command line is visible to every
user of the machine, so the key never goes there).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m r2s_eval.serve", description=__doc__.split("\n\n")[0])
    p.add_argument("path", help="LeRobot pretrained_model folder, or a training output folder holding one")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    p.add_argument("--port", type=int, default=8000, help="port to listen on (0: any free port)")
    p.add_argument("--device", default="cpu", help="torch device for the model")
    p.add_argument("--name", default=None, help="policy name (default: the checkpoint's policy type)")
    p.add_argument("--api-key-env", default=None, metavar="ENVVAR",
                   help="require the API key held in this environment variable")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not args.debug:
        logging.getLogger("websockets").setLevel(logging.WARNING)  # one line per handshake otherwise

    api_key = None
    if args.api_key_env is not None:
        api_key = os.environ.get(args.api_key_env)
        if not api_key:
            print(f"error: environment variable {args.api_key_env} (the API key) is not set", file=sys.stderr)
            return 2

    from r2s_eval.policies.lerobot_policy import load_lerobot_policy
    from r2s_eval.serving.policy_server import PolicyServer, ws_url

    try:
        policy = load_lerobot_policy(args.path, args.device, args.name)
    except Exception as exc:
        if args.debug:
            raise
        print(f"error: cannot load a policy from {args.path}: {exc}", file=sys.stderr)
        return 2
    if getattr(policy, "n_obs_steps", 1) > 1:
        # A server sees only the observations of chunk queries, not every control step.
        print(f"error: {args.path} conditions on {policy.n_obs_steps} consecutive observations; "
              "serving supports single-observation policies", file=sys.stderr)
        return 2

    if api_key is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        logging.warning("serving on %s without an API key: anyone who reaches it can use it", args.host)
    server = PolicyServer(policy, host=args.host, port=args.port, api_key=api_key)

    def ready(port: int) -> None:
        print(f"serving {policy.name} on {ws_url(args.host, port)}", flush=True)

    try:
        server.serve_forever(on_ready=ready)
    except OSError as exc:  # port taken, address not available
        if args.debug:
            raise
        print(f"error: cannot listen on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 2
    finally:
        policy.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
