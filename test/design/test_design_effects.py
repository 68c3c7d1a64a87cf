"""
``design`` carries what the identification found (issue 31).

The effects go into ``sim_motor.yaml``, kS is the break-away friction of a Stribeck effect,
the notes name what the controller ignores, kG comes from a load torque taken as gravity.
"""

import json

import pytest
import yaml

from dcmotor_id.cli.main import main
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.design.control import design
from dcmotor_id.design.export import write_exports
from dcmotor_id.design.plant import DesignOptions, motor_from_result
from dcmotor_id.identification.effects import parse_effect

STRIBECK = {'name': 'stribeck', 'parameters': {'excess_Nm': 0.5, 'velocity_rad_s': 3.0}}
LOAD = {'name': 'load_torque', 'parameters': {'torque_Nm': 0.3}}


def result_with(*effects, mode='full'):
    """Return an identify-like result of paper motor 2 with ``effects``."""
    values = PAPER_MOTORS['paper2'].as_dict(derived=False)
    if mode == 'mechanical':
        values = {name: values[name] for name in ('J', 'b', 'Mc')}
    return {'parameters': values, 'stderr': {name: 0.01 * value for name, value in values.items()},
            'mode': mode, 'torque_constant': 0.7 if mode == 'mechanical' else None,
            'effects': list(effects)}


def test_ks_is_the_breakaway_friction_of_a_stribeck_effect():
    p = PAPER_MOTORS['paper2']
    made, _ = design(motor_from_result(result_with(STRIBECK)), DesignOptions())
    feedforward = made['feedforward']
    assert feedforward['kS'] == pytest.approx(p.Ra * (p.Mc + 0.5) / p.CPhi)
    assert feedforward['kS_coulomb'] == pytest.approx(p.Ra * p.Mc / p.CPhi)
    assert 'break-away' in feedforward['kS_source']
    plain, _ = design(motor_from_result(result_with()), DesignOptions())
    assert plain['feedforward']['kS'] == pytest.approx(p.Ra * p.Mc / p.CPhi)
    assert 'kS_coulomb' not in plain['feedforward']


def test_breakaway_on_the_output_shaft_and_in_mechanical_mode():
    p = PAPER_MOTORS['paper2']
    geared = motor_from_result(result_with(STRIBECK), gear_ratio=4.0, output_shaft=True)
    made, _ = design(geared, DesignOptions())
    assert made['feedforward']['kS'] == pytest.approx(p.Ra * 4.0 * (p.Mc + 0.5) / (4.0 * p.CPhi))
    mechanical = motor_from_result(result_with(STRIBECK, mode='mechanical'))
    made, _ = design(mechanical, DesignOptions())
    assert made['feedforward']['kS'] == pytest.approx(p.Mc + 0.5)
    assert made['feedforward']['current']['kS'] == pytest.approx((p.Mc + 0.5) / 0.7)


def test_notes_name_every_effect_the_controller_ignores():
    made, _ = design(motor_from_result(result_with(STRIBECK, LOAD)), DesignOptions())
    stribeck = [note for note in made['notes'] if note.startswith('effect stribeck')]
    load = [note for note in made['notes'] if note.startswith('effect load_torque')]
    assert len(stribeck) == 1 and 'ignore' in stribeck[0] and 'break-away' in stribeck[0]
    assert len(load) == 1 and 'integral' in load[0]
    plain, _ = design(motor_from_result(result_with()), DesignOptions())
    assert not [note for note in plain['notes'] if note.startswith('effect ')]


def test_sim_motor_yaml_carries_the_effects(tmp_path):
    result = result_with(STRIBECK, LOAD)
    motor = motor_from_result(result)
    paths = write_exports(str(tmp_path), motor, motor.values)
    with open(paths['sim_motor'], encoding='utf-8') as stream:
        node = yaml.safe_load(stream)['sim_motor']['ros__parameters']
    entries = node['effects'].split(';')
    parsed = [parse_effect(entry) for entry in entries]
    assert [effect.name for effect in parsed] == ['stribeck', 'load_torque']
    assert parsed[0].parameters['excess_Nm'] == 0.5
    assert parsed[0].parameters['velocity_rad_s'] == 3.0
    assert parsed[1].parameters['torque_Nm'] == 0.3


def test_cli_design_with_effects_and_an_unknown_one(tmp_path, capsys):
    source = tmp_path / 'result.json'
    source.write_text(json.dumps(result_with(STRIBECK)))
    out = tmp_path / 'design.json'
    assert main(['design', str(source), '--export', str(tmp_path / 'export'),
                 '--json', str(out)]) == 0
    made = json.loads(out.read_text())
    assert any(note.startswith('effect stribeck') for note in made['notes'])
    assert 'stribeck:' in (tmp_path / 'export' / 'sim_motor.yaml').read_text()
    source.write_text(json.dumps(result_with({'name': 'warp_drive', 'parameters': {}})))
    capsys.readouterr()
    assert main(['design', str(source), '--export', str(tmp_path / 'again')]) == 2
    assert "effect 'warp_drive'" in capsys.readouterr().err
    assert not (tmp_path / 'again').exists()  # refused before any file is written


def test_kg_from_a_load_torque_taken_as_gravity(tmp_path, capsys):
    p = PAPER_MOTORS['paper2']
    source = tmp_path / 'result.json'
    source.write_text(json.dumps(result_with(LOAD)))
    out = tmp_path / 'design.json'
    assert main(['design', str(source), '--gravity-load', '--json', str(out)]) == 0
    feedforward = json.loads(out.read_text())['feedforward']
    assert feedforward['kG'] == pytest.approx(p.Ra * 0.3 / p.CPhi)
    assert 'ElevatorFeedforward' in feedforward['convention']
    assert 'kG = ' in capsys.readouterr().out
    assert main(['design', str(source), '--json', str(out)]) == 0
    assert 'kG' not in json.loads(out.read_text())['feedforward']
    source.write_text(json.dumps(result_with(STRIBECK)))
    assert main(['design', str(source), '--gravity-load']) == 2
    assert 'no load_torque effect' in capsys.readouterr().err
    source.write_text(json.dumps(result_with(LOAD, mode='mechanical')))
    assert main(['design', str(source), '--gravity-load', '--json', str(out)]) == 0
    feedforward = json.loads(out.read_text())['feedforward']
    assert feedforward['kG'] == pytest.approx(0.3)
    assert feedforward['current']['kG'] == pytest.approx(0.3 / 0.7)
