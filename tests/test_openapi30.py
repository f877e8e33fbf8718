"""The 3.1 -> 3.0 converter on the constructs FastAPI/pydantic emit (pure, no app)."""

from __future__ import annotations

from app.api.openapi30 import document_30, schema_30


def test_nullable_forms() -> None:
    assert schema_30({"anyOf": [{"type": "number"}, {"type": "null"}], "title": "Radius"}) == {
        "type": "number", "title": "Radius", "nullable": True}
    assert schema_30({"type": ["string", "null"]}) == {"type": "string", "nullable": True}
    assert schema_30({"anyOf": [{"$ref": "#/components/schemas/A"}, {"type": "null"}]}) == {
        "allOf": [{"$ref": "#/components/schemas/A"}], "nullable": True}
    assert schema_30({"anyOf": [{"type": "integer"}, {"type": "string"}, {"type": "null"}]}) == {
        "anyOf": [{"type": "integer"}, {"type": "string"}], "nullable": True}


def test_keywords_3_0_spells_differently() -> None:
    assert schema_30({"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1}) == {
        "type": "number", "minimum": 0, "exclusiveMinimum": True, "maximum": 1,
        "exclusiveMaximum": True}
    assert schema_30({"const": "Feature"}) == {"enum": ["Feature"]}
    assert schema_30({"type": "string", "examples": ["a", "b"]}) == {
        "type": "string", "example": "a"}
    assert schema_30({"type": "array", "prefixItems": [{"type": "number"}, {"type": "number"}],
                      "minItems": 2, "maxItems": 2}) == {
        "type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}
    assert schema_30({"type": "object", "$schema": "x", "contentMediaType": "y",
                      "x-ogc-role": "id"}) == {"type": "object", "x-ogc-role": "id"}
    nested = schema_30({"type": "object", "properties": {"a": {"type": ["integer", "null"]}},
                        "additionalProperties": {"const": 1}, "items": {"const": 2}})
    assert nested["properties"]["a"] == {"type": "integer", "nullable": True}
    assert nested["additionalProperties"] == {"enum": [1]} and nested["items"] == {"enum": [2]}


def test_document_parts() -> None:
    doc = {"openapi": "3.1.0", "info": {"title": "t", "version": "1", "summary": "s",
                                        "license": {"name": "MIT", "identifier": "MIT"}},
           "jsonSchemaDialect": "x", "webhooks": {},
           "paths": {"/a": {"parameters": [], "get": {
               "parameters": [{"name": "q", "in": "query",
                               "schema": {"anyOf": [{"type": "integer"}, {"type": "null"}]}}],
               "requestBody": {"content": {"application/json": {"schema": {"const": 1}}}},
               "responses": {"200": {"description": "ok", "content": {
                   "application/json": {"schema": {"type": ["string", "null"]}}}}}}}},
           "components": {"schemas": {"A": {"examples": [3]}}}}
    out = document_30(doc)
    assert out["openapi"] == "3.0.3" and "webhooks" not in out and "jsonSchemaDialect" not in out
    assert out["info"] == {"title": "t", "version": "1", "license": {"name": "MIT"}}
    get = out["paths"]["/a"]["get"]
    assert get["parameters"][0]["schema"] == {"type": "integer", "nullable": True}
    assert get["requestBody"]["content"]["application/json"]["schema"] == {"enum": [1]}
    assert get["responses"]["200"]["content"]["application/json"]["schema"] == {
        "type": "string", "nullable": True}
    assert out["components"]["schemas"]["A"] == {"example": 3}
    assert doc["openapi"] == "3.1.0"  # the input is left alone
