"""Reference speed profiles V_zad(X): the scenario's driving script run noise-free on the models.

The paper's linearised filter (13)-(19) linearises around a planned speed V_zad(X). An ATO
plans it from the timetable and the nominal car; here the plan is the scenario's own driver
on the nominal car (the estimator's initial mass and resistance), without noise, in still air
and without passengers boarding, run by the harness's one closed loop (harness.run.driver.drive).
"""
from __future__ import annotations

from dataclasses import replace

from models.chain import ChainConfig
from models.compiled import open_chain
from models.plant.dynamics import VehicleParams
from models.filtering.motion_filter import FilterConfig

from harness.run.driver import ChainStepper, drive
from harness.run.phases import Demands
from harness.run.scenario import Scenario


class _NoBoarding:
    """A driver whose payload changes are dropped: the nominal car stays empty."""

    def __init__(self, driver):
        self.driver = driver

    @property
    def finished(self) -> bool:
        return self.driver.finished

    def demands(self, t, outputs) -> Demands:
        d = self.driver.demands(t, outputs)
        return Demands(d.traction, d.brake)


def plan_speed_profile(scenario: Scenario, spacing_m: float = 10.0) -> tuple[list[float], list[float]]:
    """(distances [m], speeds [m/s]) of the nominal noise-free run up to its first stop."""
    setup = scenario.chain_setup()
    car, ident = setup.config.vehicle, setup.config.identifier
    vehicle = VehicleParams(mass=ident.mass_initial, A0=ident.A0_initial, A1=ident.A1_initial,
                            A2=ident.A2_initial, gamma=car.gamma, length=car.length,
                            traction_force_max=car.traction_force_max,
                            traction_power_max=car.traction_power_max,
                            brake_force_max=car.brake_force_max)
    chain = open_chain(ChainConfig(vehicle=vehicle, process_noise_psd=0.0,
                                   filter=FilterConfig(speed_std=1e-9, position_std=1e-9)), setup.grade)
    moved = False

    def first_stop(out) -> bool:
        nonlocal moved
        moved = moved or out["car.speed"] > 0
        return moved and out["car.speed"] <= 0.0

    nominal = replace(scenario, wind=(), stop_after_last_phase=False)
    trace = drive(ChainStepper(chain), nominal, _NoBoarding(scenario.new_driver(vehicle.mass)),
                  until=first_stop)
    xs, vs = [0.0], [0.0]
    moved = False
    for out in trace.outputs[1:]:
        speed, position = out["car.speed"], out["car.position"]
        moved = moved or speed > 0
        if position >= xs[-1] + spacing_m or (moved and speed <= 0.0):
            if position > xs[-1]:
                xs.append(position)
                vs.append(speed)
    return xs, vs


def profile_csv_text(distances, speeds) -> str:
    return "distance_m,speed_mps\n" + "".join(f"{d:.3f},{v:.4f}\n" for d, v in zip(distances, speeds))
