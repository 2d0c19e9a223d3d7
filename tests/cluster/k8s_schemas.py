"""JSON schemas for kubeconform, made offline: Kubernetes' from the OpenAPI spec in the
k8s.io/kubernetes module's sources, custom resources' from their CRDs.

kubeconform finds the schema of a resource by a path template; given a directory
``ROOT`` (``-schema-location ROOT``) and ``-kubernetes-version V``, it reads
``ROOT/vV-standalone[-strict]/<kind><suffix>.json``: the kind in lower case, the suffix
``-<first label of the API group>-<version>`` (``deployment-apps-v1.json``,
``clusterrole-rbac-v1.json``; ``-v1`` alone for the core group: ``service-v1.json``).
``-strict`` takes the ``-strict`` directory, whose schemas refuse fields they do not
name. Each file here is a draft-04 JSON schema (kubeconform's default draft) that
stands alone: the definitions it uses, and only those, are in its own
``definitions``, referred to as ``#/definitions/<name>``.

From the spec's ``definitions`` (``api/openapi-spec/swagger.json``, OpenAPI 2), every
one that names a group, version and kind (``x-kubernetes-group-version-kind``) is a
file; the spec's types are read as the API server decodes them:

- a field may be ``null`` (JSON null leaves a field unset when Go decodes it);
- ``IntOrString`` is an integer or a string, ``Quantity`` a string of the quantity
  grammar (``100m``, ``1Gi``, ``2e3``) or a number;
- ``format: int32`` / ``int64`` bound the integer;
- ``JSONSchemaPropsOr{Bool,Array,StringArray}`` (a CRD's schema) are a schema or what
  the name says, so a CRD's nested schemas are checked too;
- strict: an object that lists its properties gets ``additionalProperties: false``
  (maps keep their ``additionalProperties``; objects the spec leaves open, such as
  ``RawExtension``, stay open);
- the root's ``apiVersion`` and ``kind`` are pinned (kubeconform picks a file by the
  group's first label only: ``apps.example.com/v1`` would otherwise pass as ``apps/v1``).

A CRD's ``openAPIV3Schema`` (a structural schema, already JSON schema) is read as the
API server's field validation reads it: ``nullable``, ``x-kubernetes-int-or-string``,
``x-kubernetes-preserve-unknown-fields`` (an object left open),
``x-kubernetes-embedded-resource``; strict, every other object refuses fields it does
not name, as ``kubectl apply`` does (server-side strict field validation, the default
since Kubernetes 1.27, over the API server's pruning). Its root gets ``apiVersion``,
``kind`` and ``metadata`` (Kubernetes' ObjectMeta). CEL rules
(``x-kubernetes-validations``) are left to the API server.

Kubernetes' schemas are made once per version and generator into the cache
(``EDGERV_CACHE``, ``~/.cache/edgerv``): ``k8s-v<version>/schemas-<hash of this
file>/``, by ``tests/cluster/build.sh schemas``. Command line::

    k8s_schemas.py kubernetes --swagger SWAGGER.json --version 1.33.13 [--cache DIR]
    k8s_schemas.py crds --version 1.33.13 --out DIR [--cache DIR] CRD.yaml...

Each prints the directory to give kubeconform's ``-schema-location``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

Schema = dict[str, Any]

DRAFT = "http://json-schema.org/draft-04/schema#"
META = "io.k8s.apimachinery.pkg.apis.meta.v1."
EXT = "io.k8s.apiextensions-apiserver.pkg.apis.apiextensions.v1."
OBJECT_META = META + "ObjectMeta"
# The quantity grammar (k8s.io/apimachinery/pkg/api/resource): a signed decimal, then a
# binary suffix (Ki..Ei), a decimal one (n, u, m, k, M..E) or an exponent (e3, E-2).
QUANTITY = r"^[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([KMGTPE]i|[numkMGTPE]|[eE][+-]?[0-9]+)?$"
BOUNDS = {"int32": (-(2**31), 2**31 - 1), "int64": (-(2**63), 2**63 - 1)}
# Keywords carried over as they are (draft-04; the rest, x-kubernetes-* and OpenAPI's
# own, are read below or dropped).
PLAIN = (
    "description", "enum", "format", "minimum", "maximum", "exclusiveMinimum",
    "exclusiveMaximum", "minLength", "maxLength", "pattern", "minItems", "maxItems",
    "uniqueItems", "minProperties", "maxProperties", "multipleOf", "required",
)  # fmt: skip


def cache_dir() -> Path:
    return Path(os.environ.get("EDGERV_CACHE", Path.home() / ".cache" / "edgerv"))


def fingerprint() -> str:
    """What the schemas depend on besides the spec: this file."""
    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:12]


def kubernetes_root(version: str, cache: Path | None = None) -> Path:
    """Where Kubernetes ``version``'s schemas are (made by ``kubernetes``)."""
    return (cache or cache_dir()) / f"k8s-v{version}" / f"schemas-{fingerprint()}"


def variant(root: Path, version: str, strict: bool) -> Path:
    return root / f"v{version}-standalone{'-strict' if strict else ''}"


def file_name(kind: str, group: str, version: str) -> str:
    """kubeconform's ``{{ .ResourceKind }}{{ .KindSuffix }}.json``."""
    suffix = f"-{group.split('.')[0].lower()}-{version.lower()}" if group else f"-{version}"
    return f"{kind.lower()}{suffix}.json"


def _nullable(schema: Schema) -> Schema:
    types = schema.get("type")
    if isinstance(types, str):
        schema["type"] = [types, "null"]
    elif isinstance(types, list) and "null" not in types:
        schema["type"] = [*types, "null"]
    return schema


def _ref(name: str) -> Schema:
    return {"$ref": f"#/definitions/{name}"}


def _common(node: Schema, out: Schema) -> None:
    for key in PLAIN:
        if key in node:
            out[key] = node[key]
    bounds = BOUNDS.get(node.get("format", ""))
    if bounds and node.get("type") == "integer":
        out.setdefault("minimum", bounds[0])
        out.setdefault("maximum", bounds[1])


def _openapi(node: Schema, strict: bool, uses: set[str]) -> Schema:
    """One node of the OpenAPI 2 spec's definitions, as draft-04 JSON schema."""
    ref = node.get("$ref")
    if ref:  # its siblings (a description) mean nothing beside a $ref
        name = ref.rsplit("/", 1)[-1]
        uses.add(name)
        return _ref(name)
    out: Schema = {}
    _common(node, out)
    if "type" in node:
        out["type"] = node["type"]
    if node.get("format") == "int-or-string":
        out["type"] = ["integer", "string"]
        del out["format"]
    if "properties" in node:
        out["properties"] = {k: _openapi(v, strict, uses) for k, v in node["properties"].items()}
        if strict:
            out["additionalProperties"] = False
    if isinstance(node.get("additionalProperties"), dict):
        out["additionalProperties"] = _openapi(node["additionalProperties"], strict, uses)
    if "items" in node:
        out["items"] = _openapi(node["items"], strict, uses)
    return _nullable(out)


def _special(name: str) -> Schema | None:
    """The definitions whose JSON is not what the OpenAPI spec's types say."""
    props = _ref(EXT + "JSONSchemaProps")
    null = {"type": "null"}
    if name == "io.k8s.apimachinery.pkg.api.resource.Quantity":
        return {"type": ["string", "number", "null"], "pattern": QUANTITY}
    if name == EXT + "JSONSchemaPropsOrBool":
        return {"anyOf": [{"type": "boolean"}, props, null]}
    if name == EXT + "JSONSchemaPropsOrArray":
        return {"anyOf": [props, {"type": "array", "items": props}, null]}
    if name == EXT + "JSONSchemaPropsOrStringArray":
        return {"anyOf": [props, {"type": "array", "items": {"type": "string"}}, null]}
    return None


def convert_definitions(definitions: dict[str, Schema], strict: bool) -> dict[str, Any]:
    """Every definition, converted, with the names each one refers to."""
    out: dict[str, Any] = {}
    for name, node in definitions.items():
        uses: set[str] = set()
        special = _special(name)
        if special is not None:
            for s in special.get("anyOf", []):
                if "$ref" in s or "$ref" in s.get("items", {}):
                    uses.add(EXT + "JSONSchemaProps")
            schema = {**special, "description": node.get("description", "")}
        else:
            schema = _openapi(node, strict, uses)
        out[name] = {"schema": schema, "uses": sorted(uses)}
    return out


def closure(converted: dict[str, Any], start: Iterable[str]) -> dict[str, Schema]:
    """The definitions reachable from ``start``, by name."""
    seen: dict[str, Schema] = {}
    todo = list(start)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        if name not in converted:
            raise KeyError(f"the spec refers to {name}, which it does not define")
        seen[name] = converted[name]["schema"]
        todo.extend(converted[name]["uses"])
    return dict(sorted(seen.items()))


def _document(root: Schema, converted: dict[str, Any], uses: Iterable[str]) -> Schema:
    defs = closure(converted, uses)
    return {"$schema": DRAFT, **root, **({"definitions": defs} if defs else {})}


def _pin(root: Schema, group: str, version: str, kind: str) -> Schema:
    """The root as kubeconform reads it: an object (never null) of this very kind."""
    api_version = f"{group}/{version}" if group else version
    root = {**root, "type": "object", "properties": dict(root.get("properties", {}))}
    for key, value in (("apiVersion", api_version), ("kind", kind)):
        described = root["properties"].get(key, {}).get("description")
        root["properties"][key] = {"type": "string", "enum": [value]}
        if described:
            root["properties"][key]["description"] = described
    return root


def _write_atomically(final: Path, fill: Any) -> None:
    """Make ``final`` by ``fill(tmpdir)`` into a sibling, then one rename."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=final.parent))
    try:
        fill(tmp)
        if final.exists():  # another made it meanwhile: keep theirs
            shutil.rmtree(tmp)
        else:
            tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _dump(path: Path, schema: Schema) -> None:
    path.write_text(json.dumps(schema, sort_keys=True, separators=(",", ":")))


def make_kubernetes(swagger: Path, version: str, root: Path) -> int:
    """Every kind of the spec, plain and strict, into ``root``; returns the kinds' count.
    Also writes ``_definitions.json`` (converted) for the CRDs' metadata."""
    definitions: dict[str, Schema] = json.loads(swagger.read_text())["definitions"]
    kinds = [
        (g["group"], g["version"], g["kind"], name)
        for name, node in definitions.items()
        for g in node.get("x-kubernetes-group-version-kind", [])
    ]

    def fill(tmp: Path) -> None:
        for strict in (False, True):
            converted = convert_definitions(definitions, strict)
            where = variant(tmp, version, strict)
            where.mkdir(parents=True)
            made: dict[str, str] = {}
            for group, ver, kind, name in kinds:
                file = file_name(kind, group, ver)
                if made.get(file, name) != name:
                    raise ValueError(f"{file}: both {made[file]} and {name}")
                made[file] = name
                root = _pin(converted[name]["schema"], group, ver, kind)
                _dump(where / file, _document(root, converted, converted[name]["uses"]))
            _dump(where / "_definitions.json", {k: v["schema"] for k, v in converted.items()})

    if not root.exists():
        _write_atomically(root, fill)
        for old in root.parent.glob("schemas-*"):  # those of an earlier generator
            if old != root and not old.name.startswith("."):
                shutil.rmtree(old, ignore_errors=True)
    return len(list(variant(root, version, True).glob("*-*.json")))


def _structural(node: Schema, strict: bool, uses: set[str]) -> Schema:
    """One node of a CRD's structural schema, as the API server validates it."""
    out: Schema = {}
    _common(node, out)
    if "type" in node:
        out["type"] = node["type"]
    if node.get("x-kubernetes-int-or-string"):
        out["type"] = ["integer", "string"]
    for key in ("allOf", "anyOf", "oneOf"):
        if key in node:
            out[key] = [_structural(s, strict, uses) for s in node[key]]
    if "not" in node:
        out["not"] = _structural(node["not"], strict, uses)
    if "items" in node:
        out["items"] = _structural(node["items"], strict, uses)
    props = {k: _structural(v, strict, uses) for k, v in node.get("properties", {}).items()}
    if node.get("x-kubernetes-embedded-resource"):
        uses.add(OBJECT_META)
        props = {"apiVersion": {"type": "string"}, "kind": {"type": "string"},
                 "metadata": _ref(OBJECT_META), **props}  # fmt: skip
    if props:
        out["properties"] = props
    extra = node.get("additionalProperties")
    if isinstance(extra, dict):
        out["additionalProperties"] = _structural(extra, strict, uses)
    elif isinstance(extra, bool):
        out["additionalProperties"] = extra
    elif (
        strict
        and node.get("type") == "object"
        and not node.get("x-kubernetes-preserve-unknown-fields")
    ):
        out["additionalProperties"] = False  # pruned by the server: refused, strict
    if node.get("nullable"):
        _nullable(out)
    return out


def make_crds(crds: Iterable[Schema], version: str, out: Path, kubernetes: Path) -> list[str]:
    """The schema of each version of each CRD, plain and strict, into ``out`` (made
    anew); ``kubernetes``: Kubernetes' schemas (for ObjectMeta). Returns the files'
    names."""
    crds = [c for c in crds if c and c.get("kind") == "CustomResourceDefinition"]
    names: list[str] = []
    if out.exists():
        shutil.rmtree(out)
    for strict in (False, True):
        defs = json.loads((variant(kubernetes, version, strict) / "_definitions.json").read_text())
        converted = {
            name: {"schema": schema, "uses": sorted(_refs(schema))} for name, schema in defs.items()
        }
        where = variant(out, version, strict)
        where.mkdir(parents=True)
        for crd in crds:
            spec = crd["spec"]
            group, kind = spec["group"], spec["names"]["kind"]
            for ver in spec["versions"]:
                schema = ver.get("schema", {}).get("openAPIV3Schema")
                if schema is None:
                    continue
                uses = {OBJECT_META}
                root = _structural(schema, strict, uses)
                # metadata is ObjectMeta whatever the CRD says (controller-gen writes a
                # bare object there; the API server validates ObjectMeta)
                root["properties"] = {**root.get("properties", {}), "metadata": _ref(OBJECT_META)}
                root = _pin(root, group, ver["name"], kind)
                file = file_name(kind, group, ver["name"])
                _dump(where / file, _document(root, converted, uses))
                if strict:
                    names.append(file)
    return sorted(names)


def _refs(schema: Any) -> set[str]:
    found: set[str] = set()
    if isinstance(schema, dict):
        ref = schema.get("$ref")
        if isinstance(ref, str):
            found.add(ref.rsplit("/", 1)[-1])
        for value in schema.values():
            found |= _refs(value)
    elif isinstance(schema, list):
        for value in schema:
            found |= _refs(value)
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    k8s = sub.add_parser("kubernetes", help="Kubernetes' schemas, once per version")
    k8s.add_argument("--swagger", type=Path, required=True, help="api/openapi-spec/swagger.json")
    crd = sub.add_parser("crds", help="the schemas of CRDs (YAML files)")
    crd.add_argument("--out", type=Path, required=True)
    crd.add_argument("files", type=Path, nargs="+")
    for p in (k8s, crd):
        p.add_argument("--version", required=True, help="Kubernetes', e.g. 1.33.13")
        p.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args(argv)
    root = kubernetes_root(args.version, args.cache)
    if args.what == "kubernetes":
        made = root.exists()
        count = make_kubernetes(args.swagger, args.version, root)
        print(f"{'kept' if made else 'made'} {count} schemas of Kubernetes v{args.version}: {root}")
        return 0
    import yaml  # only here: the Kubernetes part needs the standard library alone

    docs = [d for f in args.files for d in yaml.safe_load_all(f.read_text())]
    if not root.exists():
        sys.exit(f"no schemas of Kubernetes v{args.version} at {root}: build.sh schemas")
    for name in make_crds(docs, args.version, args.out, root):
        print(f"{args.out}: {name}", file=sys.stderr)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
