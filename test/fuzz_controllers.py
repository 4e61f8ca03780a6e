"""Hostile controllers for the fuzz tests (test_fuzz_scenarios.py), run by ``cvt-sim scenario run
--controller fuzz_controllers:make``: the scenario's ``description`` says, as JSON, what the
controller answers from which period on, or what its factory does. Kinds:

* ``number``: ``value`` (a JSON number: huge integers, 1e308, -0.0 …) — a real crank length;
* ``nan`` / ``inf`` / ``-inf``; ``text`` (``value`` as a str: '0.05'); ``bool``; ``none``;
  ``list``, ``dict``, ``complex``, ``bytes``; ``numpy`` (``value`` as numpy's ``dtype``:
  float64, float32, int64, bool_, …); ``fraction``, ``decimal``;
* ``float_raises`` (a numbers.Real whose ``__float__`` raises ``error``), ``index_only``
  (``__index__`` but no ``__float__``), ``repr_raises`` (neither float nor repr works);
* ``raise`` (the call raises ``error``: ValueError, ZeroDivisionError, SystemExit,
  RecursionError, KeyError, …);
* ``factory_raises``, ``factory_returns`` (the factory itself fails or returns ``value``).
"""
import decimal
import fractions
import json
import numbers

import numpy as np

ERRORS = {'ValueError': ValueError, 'ZeroDivisionError': ZeroDivisionError,
          'SystemExit': SystemExit, 'RecursionError': RecursionError, 'KeyError': KeyError,
          'TypeError': TypeError, 'OverflowError': OverflowError, 'AttributeError': AttributeError}


class FloatRaises:
    """A numbers.Real (registered) that cannot be a float."""

    def __init__(self, error):
        self.error = error

    def __float__(self):
        raise self.error('no float for you')


numbers.Real.register(FloatRaises)


class IndexOnly:
    def __index__(self):
        return 1


class ReprRaises:
    def __float__(self):
        raise ValueError('no')

    def __repr__(self):
        raise RuntimeError('no repr either')


def answer(spec):
    """The value a controller of this ``spec`` answers (or raises)."""
    kind, value = spec['kind'], spec.get('value')
    error = ERRORS.get(spec.get('error'), ValueError)
    made = {
        'number': lambda: value, 'nan': lambda: float('nan'), 'inf': lambda: float('inf'),
        '-inf': lambda: float('-inf'), 'text': lambda: str(value), 'bool': lambda: bool(value),
        'none': lambda: None, 'list': lambda: [value], 'dict': lambda: {'a': value},
        'complex': lambda: complex(0.04, 1.0), 'bytes': lambda: b'0.04',
        'numpy': lambda: np.array(0.04 if value != 'bool_' else True).astype(value)[()],
        'fraction': lambda: fractions.Fraction(1, 25), 'decimal': lambda: decimal.Decimal('0.04'),
        'float_raises': lambda: FloatRaises(error), 'index_only': IndexOnly,
        'repr_raises': ReprRaises,
    }
    if kind == 'raise':
        raise error('the controller failed on purpose')
    return made[kind]()


def make(scenario):
    spec = json.loads(scenario.description)
    if spec['kind'] == 'factory_raises':
        raise ERRORS.get(spec.get('error'), ValueError)('the factory failed on purpose')
    if spec['kind'] == 'factory_returns':
        return spec.get('value')
    start = int(spec.get('at', 0))

    def controller(measurement):
        if controller.k < start:
            controller.k += 1
            return None
        return answer(spec)
    controller.k = 0
    return controller
