"""Turn the OpenAPI 3.1 document FastAPI writes into OpenAPI 3.0.3.

OGC API Features' ``oas30`` conformance class, QGIS and GDAL all expect 3.0, and FastAPI only
writes 3.1 (pydantic 2 emits JSON Schema 2020-12). The differences that occur in practice are
few and mechanical, so a pure function rewrites them rather than a second document being kept
by hand:

- ``anyOf: [X, {type: null}]`` / ``type: [X, "null"]`` -> ``X`` with ``nullable: true``;
- numeric ``exclusiveMinimum: n`` -> ``minimum: n, exclusiveMinimum: true`` (and maximum);
- ``const: v`` -> ``enum: [v]``; schema ``examples: [..]`` -> ``example``;
- ``prefixItems`` (tuples) -> ``items`` accepting any of the listed types;
- keywords 3.0 does not know (``$schema``, ``$id``, ``contentMediaType``, ...) are dropped.
"""

from __future__ import annotations

from typing import Any

VERSION = "3.0.3"
# Schema keywords of OpenAPI 3.0's Schema Object; anything else is 3.1 / 2020-12 only.
SCHEMA_KEYWORDS = frozenset({
    "title", "multipleOf", "maximum", "exclusiveMaximum", "minimum", "exclusiveMinimum",
    "maxLength", "minLength", "pattern", "maxItems", "minItems", "uniqueItems",
    "maxProperties", "minProperties", "required", "enum", "type", "allOf", "oneOf", "anyOf",
    "not", "items", "properties", "additionalProperties", "description", "format", "default",
    "nullable", "discriminator", "readOnly", "writeOnly", "xml", "externalDocs", "example",
    "deprecated", "$ref",
})
SCHEMA_MAPS = ("properties",)
SCHEMA_LISTS = ("allOf", "oneOf", "anyOf")
SCHEMA_ONE = ("items", "not", "additionalProperties")


def _is_null(schema: Any) -> bool:
    return isinstance(schema, dict) and schema.get("type") == "null" and len(schema) == 1


def schema_30(schema: Any) -> Any:
    """One JSON Schema 2020-12 object as an OpenAPI 3.0 Schema Object."""
    if not isinstance(schema, dict):
        return schema
    out: dict[str, Any] = {}
    nullable = False
    for key, value in schema.items():
        if key in SCHEMA_MAPS and isinstance(value, dict):
            out[key] = {name: schema_30(sub) for name, sub in value.items()}
        elif key in SCHEMA_LISTS and isinstance(value, list):
            kept = [schema_30(sub) for sub in value if not _is_null(sub)]
            nullable = nullable or len(kept) < len(value)
            if len(kept) == 1 and key != "allOf":
                out.update(kept[0])  # anyOf [X] (null dropped) is just X
            elif kept:
                out[key] = kept
        elif key in SCHEMA_ONE:
            out[key] = schema_30(value)
        elif key == "type" and isinstance(value, list):
            types = [t for t in value if t != "null"]
            nullable = nullable or len(types) < len(value)
            if len(types) == 1:
                out["type"] = types[0]
            elif types:
                out["anyOf"] = [{"type": t} for t in types]
        elif key in ("exclusiveMinimum", "exclusiveMaximum") and not isinstance(value, bool):
            out["minimum" if key == "exclusiveMinimum" else "maximum"] = value
            out[key] = True
        elif key == "const":
            out["enum"] = [value]
        elif key == "examples" and isinstance(value, list) and value:
            out["example"] = value[0]
        elif key == "prefixItems" and isinstance(value, list):
            options = [schema_30(sub) for sub in value]
            unique = [o for i, o in enumerate(options) if o not in options[:i]]
            out["items"] = unique[0] if len(unique) == 1 else {"anyOf": unique}
        elif key in SCHEMA_KEYWORDS or key.startswith("x-"):
            out[key] = value
    if nullable:
        out["nullable"] = True
    if out.get("nullable") and "type" not in out and "$ref" in out:
        # 3.0 ignores siblings of $ref: wrap it so "nullable" counts.
        out["allOf"] = [{"$ref": out.pop("$ref")}]
    return out


def _content(content: dict[str, Any]) -> dict[str, Any]:
    return {media: {**body, **({"schema": schema_30(body["schema"])} if "schema" in body else {})}
            for media, body in content.items()}


def _parameter(param: dict[str, Any]) -> dict[str, Any]:
    out = dict(param)
    if "schema" in out:
        out["schema"] = schema_30(out["schema"])
    return out


def _operation(op: dict[str, Any]) -> dict[str, Any]:
    out = dict(op)
    if "parameters" in out:
        out["parameters"] = [_parameter(p) for p in out["parameters"]]
    if "requestBody" in out and "content" in out["requestBody"]:
        out["requestBody"] = {**out["requestBody"],
                              "content": _content(out["requestBody"]["content"])}
    if "responses" in out:
        out["responses"] = {status: {**resp, **({"content": _content(resp["content"])}
                                                if "content" in resp else {})}
                            for status, resp in out["responses"].items()}
    return out


METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")


def document_30(doc: dict[str, Any]) -> dict[str, Any]:
    """A whole OpenAPI 3.1 document as 3.0.3 (a new dict; the input is left alone)."""
    info = {k: v for k, v in doc.get("info", {}).items() if k != "summary"}
    if "license" in info:
        info["license"] = {k: v for k, v in info["license"].items() if k != "identifier"}
    paths = {path: {method: (_operation(op) if method in METHODS else op)
                    for method, op in item.items()}
             for path, item in doc.get("paths", {}).items()}
    components = dict(doc.get("components", {}))
    if "schemas" in components:
        components["schemas"] = {name: schema_30(s) for name, s in components["schemas"].items()}
    if "parameters" in components:
        components["parameters"] = {name: _parameter(p)
                                    for name, p in components["parameters"].items()}
    out = {k: v for k, v in doc.items() if k not in ("webhooks", "jsonSchemaDialect")}
    out.update(openapi=VERSION, info=info, paths=paths, components=components)
    return out
