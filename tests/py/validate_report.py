"""Validates fuse reports against schemas/report.schema.json with the jsonschema package.

Usage: validate_report.py SCHEMA REPORT... ; prints {"valid": N} and exits 0 when every
report is valid, else prints each error (file, JSON path, message) and exits 1.
"""

import json
import sys

import jsonschema


def main():
    schema = json.load(open(sys.argv[1]))
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    errors = []
    for path in sys.argv[2:]:
        for e in validator.iter_errors(json.load(open(path))):
            errors.append("%s: %s: %s" % (path, e.json_path, e.message))
    if errors:
        print("\n".join(errors))
        sys.exit(1)
    print(json.dumps({"valid": len(sys.argv) - 2}))


if __name__ == "__main__":
    main()
