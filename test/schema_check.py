"""
Validate a JSON document against the schemas of docs/schema/ (the subset they use).

``jsonschema`` validates when it is installed; otherwise this small validator of the keywords
the schemas use (type, required, properties, additionalProperties, items, enum, const,
minimum, exclusiveMinimum, minItems) does, and refuses a schema with any other keyword.
"""

import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCHEMA_DIR = os.path.join(ROOT, 'docs', 'schema')
TYPES = {'object': dict, 'array': list, 'string': str, 'boolean': bool, 'null': type(None),
         'integer': int, 'number': (int, float)}
KNOWN = {'$schema', '$id', 'title', 'description', 'type', 'required', 'properties',
         'additionalProperties', 'items', 'enum', 'const', 'minimum', 'exclusiveMinimum',
         'minItems'}


def load_schema(name):
    """Return the schema docs/schema/NAME.schema.json."""
    with open(os.path.join(SCHEMA_DIR, f'{name}.schema.json'), encoding='utf-8') as file:
        return json.load(file)


def _is_type(value, name):
    if isinstance(value, bool) and name in ('integer', 'number'):
        return False
    return isinstance(value, TYPES[name])


def errors(document, schema, where='$'):
    """Return the list of ways ``document`` breaks ``schema`` (empty: valid)."""
    unknown = set(schema) - KNOWN
    assert not unknown, f'{where}: the minimal validator does not know {unknown}'
    found = []
    kinds = schema.get('type')
    if kinds is not None:
        kinds = [kinds] if isinstance(kinds, str) else kinds
        if not any(_is_type(document, kind) for kind in kinds):
            return [f'{where}: {type(document).__name__} is not {kinds}']
    if 'const' in schema and document != schema['const']:
        found.append(f'{where}: {document!r} is not {schema["const"]!r}')
    if 'enum' in schema and document not in schema['enum']:
        found.append(f'{where}: {document!r} not in {schema["enum"]}')
    if 'minimum' in schema and document < schema['minimum']:
        found.append(f'{where}: {document} < {schema["minimum"]}')
    if 'exclusiveMinimum' in schema and document <= schema['exclusiveMinimum']:
        found.append(f'{where}: {document} <= {schema["exclusiveMinimum"]}')
    if isinstance(document, list):
        if len(document) < schema.get('minItems', 0):
            found.append(f'{where}: fewer than {schema["minItems"]} items')
        for index, item in enumerate(document):
            found += errors(item, schema.get('items', {}), f'{where}[{index}]')
    if isinstance(document, dict):
        found += [f'{where}: no {key!r}' for key in schema.get('required', [])
                  if key not in document]
        properties = schema.get('properties', {})
        extra = schema.get('additionalProperties', True)
        for key, value in document.items():
            if key in properties:
                found += errors(value, properties[key], f'{where}.{key}')
            elif extra is False:
                found.append(f'{where}: {key!r} is not allowed')
            elif isinstance(extra, dict):
                found += errors(value, extra, f'{where}.{key}')
    return found


def validate(document, name):
    """Assert that ``document`` is valid against docs/schema/NAME.schema.json."""
    schema = load_schema(name)
    try:
        import jsonschema
    except ImportError:
        problems = errors(document, schema)
        assert not problems, '\n'.join(problems)
    else:
        jsonschema.validate(document, schema)
