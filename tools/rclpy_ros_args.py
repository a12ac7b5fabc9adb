"""How rcl resolves `--ros-args` command lines: for each case of a cases file
(tests/fixtures/ros_args_cases.json, with the parameter files' paths filled in), rclpy.init with
the case's arguments and a Node 'sweepdepth' in '/' that declares its parameters from the
overrides; prints one JSON line per case: the node's name and namespace, the resolved topic names,
the parameter values, the node logger's effective level, or the error rcl raised.

Usage (inside a private network namespace: a Node opens DDS): tools/ros_python
tools/rclpy_ros_args.py CASES.json
"""

import json
import sys

import rclpy
from rclpy.context import Context
from rclpy.node import Node

STANDARD = {"start_type_description_service"}
LEVELS = {10: "debug", 20: "info", 30: "warn", 40: "error", 50: "fatal"}


def resolve(case: dict, topics: list) -> dict:
    context = Context()
    try:
        rclpy.init(args=["sweepdepth", "--ros-args", *case["args"]], context=context)
    except Exception as e:  # rcl's own refusal, whatever its class
        return {"error": f"{type(e).__name__}: {e}"}
    try:
        try:
            node = Node("sweepdepth", context=context,
                        automatically_declare_parameters_from_overrides=True)
        except Exception as e:
            return {"error": f"{type(e).__name__}: {e}"}
        out = {
            "name": node.get_name(),
            "namespace": node.get_namespace(),
            "topics": {t: node.resolve_topic_name(t) for t in topics},
            # Without the parameters every rclpy node declares for itself.
            "params": {name: p.value for name, p in node._parameters.items()
                       if name not in STANDARD},
        }
        if case.get("loggers"):
            level = node.get_logger().get_effective_level()
            out["log_level"] = LEVELS.get(int(level), str(level))
        node.destroy_node()
        return out
    finally:
        rclpy.shutdown(context=context)


def main() -> None:
    with open(sys.argv[1]) as f:
        cases = json.load(f)
    for case in cases["cases"]:
        result = resolve(case, cases["topics"])
        result["case"] = case["name"]
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
