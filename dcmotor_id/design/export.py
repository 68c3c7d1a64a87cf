"""
Model export of a design: a pickle-free StateSpace JSON, a sim_motor YAML and URDF dynamics.

Files written by :func:`write_exports` (``dcmotor-id design RESULT.json --export DIR``):

* ``model_statespace.json``: the linear motor on the controlled shaft as python-control
  builds it (:func:`dcmotor_id.design.loops.motor_model`): ``A, B, C, D``, ``dt`` (0:
  continuous),
  ``states``, ``inputs``, ``outputs``, and the parameters with their units and standard errors;
  :func:`load_statespace` rebuilds it with ``control.ss``. Coulomb friction is not linear: it
  acts on the ``torque`` input as ``-Mc sgn(w)``.
* ``sim_motor.yaml`` (full mode only): the parameters of the ``sim_motor`` node, so that
  ``sim_motor --ros-args --params-file DIR/sim_motor.yaml`` simulates the identified motor,
  its ``effects`` entry the effects the identification found (:func:`effects_text`).
* ``urdf_dynamics.xml``: ``<dynamics damping="b N^2" friction="Mc N"/>`` for the joint on the
  output shaft of a gear of ratio ``N`` (motor speed / output speed; an ideal, loss-free gear);
  not for a voltage-to-speed result (kS, kV, kA: no torque without the current).
"""

from __future__ import annotations

import json
import os
from typing import Any, Sequence

import control
import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.design.loops import motor_model
from dcmotor_id.design.plant import Motor
from dcmotor_id.formats.json_file import load_json
from dcmotor_id.identification.effects import parse_effect

#: Format tag of the StateSpace JSON.
STATESPACE_FORMAT = 'dcmotor_id.statespace/1'
_UNITS = {'Ra': 'Ohm', 'La': 'H', 'CPhi': 'V s', 'J': 'kg m^2', 'b': 'N m s/rad', 'Mc': 'N m',
          'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad', 'Ta': 's', 'kA_inertia': 'V s^2/rad'}
_SIGNAL_UNITS = {'i': 'A', 'w': 'rad/s', 'u': 'V', 'torque': 'N m', 'a': 'rad/s^2'}


def statespace_dict(motor: Motor) -> dict:
    """Return the motor model as a JSON-ready dict (no pickle, plain lists)."""
    system = motor_model(motor)
    return {
        'format': STATESPACE_FORMAT,
        'A': system.A.tolist(), 'B': system.B.tolist(), 'C': system.C.tolist(),
        'D': system.D.tolist(), 'dt': 0.0,
        'states': list(system.state_labels), 'inputs': list(system.input_labels),
        'outputs': list(system.output_labels),
        'signal_units': {name: _SIGNAL_UNITS[name] for name in
                         [*system.state_labels, *system.input_labels, *system.output_labels]},
        'parameters': dict(motor.values), 'stderr': _finite(motor.stderr),
        'units': {name: _UNITS[name] for name in motor.values},
        'mode': motor.mode, 'shaft': motor.shaft, 'gear_ratio': motor.gear_ratio,
        'torque_constant': motor.torque_constant,
        'nonlinear': ('Coulomb friction: voltage input -kS sgn(w) (stiction at rest)'
                      if motor.mode == 'voltage_speed' else
                      'Coulomb friction: torque input -Mc sgn(w) (stiction at rest)'),
    }


def _finite(values: dict) -> dict:
    return {key: (float(value) if np.isfinite(value) else None) for key, value in values.items()}


def load_statespace(path: str) -> control.StateSpace:
    """Rebuild the StateSpace written by :func:`write_exports` with ``control.ss``."""
    with open(path, encoding='utf-8') as stream:
        data = load_json(stream)
    return control.ss(np.array(data['A'], dtype=float), np.array(data['B'], dtype=float),
                      np.array(data['C'], dtype=float), np.array(data['D'], dtype=float),
                      data['dt'] or 0, states=data['states'], inputs=data['inputs'],
                      outputs=data['outputs'])


def _yaml_double(value: float) -> str:
    """Format a float that YAML 1.1 and ROS read as a double (a point in the mantissa)."""
    text = repr(float(value))
    mantissa, _, exponent = text.partition('e')
    if '.' not in mantissa:
        mantissa += '.0'
    return mantissa + ('e' + exponent if exponent else '')


def effects_text(effects: Sequence[dict]) -> str:
    """
    Return effects as the ``sim_motor`` node's ``effects`` parameter takes them.

    ``NAME:param=value,...`` joined by ``;``; each entry is read back with
    :func:`~dcmotor_id.identification.effects.parse_effect` (what the node does), so an
    effect the vocabulary does not know is refused here, not by the node.
    """
    entries = []
    for effect in effects:
        values = ','.join(f'{key}={value!r}' if isinstance(value, float) else f'{key}={value}'
                          for key, value in effect['parameters'].items())
        entry = f"{effect['name']}:{values}" if values else effect['name']
        try:
            parse_effect(entry)
        except (KeyError, ValueError, TypeError) as error:
            raise InputDataError(f'effect {entry!r} of the result: sim_motor cannot simulate '
                                 f'it ({error}); correct or remove it in the result') from None
        entries.append(entry)
    return ';'.join(entries)


def sim_motor_yaml(values: dict, effects: Sequence[dict] = ()) -> str:
    """
    Return a ``sim_motor`` parameter file for the motor ``values`` (motor shaft, SI).

    ``effects`` (``{"name", "parameters"}`` each, motor shaft) become its ``effects`` entry.
    """
    lines = ['# The identified motor for the sim_motor node (dcmotor-id design --export).',
             '#   sim_motor --ros-args --params-file sim_motor.yaml',
             'sim_motor:', '  ros__parameters:']
    comments = {'Ra': 'armature resistance [Ohm]', 'La': 'armature inductance [H]',
                'CPhi': 'back-EMF / torque constant [V s] = [N m/A]',
                'J': 'inertia of rotor and load [kg m^2]', 'b': 'viscous friction [N m s/rad]',
                'Mc': 'Coulomb friction [N m]'}
    for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc'):
        entry = f'{name}: {_yaml_double(values[name])}'
        lines.append(f'    {entry:<28} # {comments[name]}')
    quoted = "'{}'".format(effects_text(effects).replace("'", "''"))
    lines.append(f'    effects: {quoted}  # the effects identified (sim_motor simulates them)')
    return '\n'.join(lines) + '\n'


def urdf_dynamics(values: dict, gear_ratio: float, shaft: str) -> dict:
    """
    Return the URDF joint dynamics on the output shaft.

    ``damping = b N^2`` [N m s/rad] and ``friction = Mc N`` [N m] for motor-shaft values
    (an ideal gear multiplies torque by ``N`` and divides speed by ``N``); values already on
    the output shaft are taken as they are.
    """
    n = 1.0 if shaft == 'output' else gear_ratio
    damping, friction = values['b'] * n ** 2, values['Mc'] * n
    element = f'<dynamics damping="{damping:.6g}" friction="{friction:.6g}"/>'
    return {'damping': damping, 'friction': friction, 'gear_ratio': gear_ratio,
            'element': element,
            'units': {'damping': 'N m s/rad', 'friction': 'N m'}}


def write_exports(directory: str, motor: Motor, motor_shaft_values: dict) -> dict:
    """
    Write the model files into ``directory``.

    Parameters
    ----------
    directory : str
        Created when missing.
    motor : Motor
        The motor on the controlled shaft (the StateSpace and URDF values).
    motor_shaft_values : dict
        The identified values on the motor shaft (the sim_motor file).

    Returns
    -------
    dict
        ``{'statespace': path, 'sim_motor': path or None, 'urdf': path or None,
        'urdf_dynamics': {...} or None}``.

    """
    # The sim_motor file first: an effect it cannot simulate is refused before any file.
    simulator = sim_motor_yaml(motor_shaft_values, motor.effects) if motor.mode == 'full' else ''
    os.makedirs(directory, exist_ok=True)
    paths: dict[str, Any] = {}
    path = os.path.join(directory, 'model_statespace.json')
    with open(path, 'w', encoding='utf-8') as stream:
        json.dump(statespace_dict(motor), stream, indent=2, allow_nan=False)
    paths['statespace'] = path
    paths['sim_motor'] = None
    if motor.mode == 'full':
        path = os.path.join(directory, 'sim_motor.yaml')
        with open(path, 'w', encoding='utf-8') as stream:
            stream.write(simulator)
        paths['sim_motor'] = path
    paths['urdf'] = paths['urdf_dynamics'] = None
    if motor.mode == 'voltage_speed':  # no torque without the current: no URDF friction
        return paths
    dynamics = urdf_dynamics(motor.values, motor.gear_ratio, motor.shaft)
    path = os.path.join(directory, 'urdf_dynamics.xml')
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write(f'<!-- joint on the output shaft, gear ratio {motor.gear_ratio:g} '
                     f'(damping = b N^2 [N m s/rad], friction = Mc N [N m]) -->\n'
                     f"{dynamics['element']}\n")
    paths['urdf'] = path
    paths['urdf_dynamics'] = dynamics
    return paths
