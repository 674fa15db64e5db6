"""Reference speed profiles V_zad(X): the scenario's driving script run noise-free on the models.

The paper's linearised filter (13)-(19) linearises around a planned speed V_zad(X). An ATO
plans it from the timetable and the nominal car; here the plan is the scenario's own driver
on the nominal car (the estimator's initial mass and resistance), without noise.
"""
from __future__ import annotations

from models.chain import ChainConfig
from models.compiled import open_chain
from models.dynamics import VehicleParams
from models.filters import FilterConfig
from models.track import GradeProfile

from .driver import PhaseDriver
from .scenario import Scenario, ScenarioError, profile_file
from .textio import read_text


def plan_speed_profile(scenario: Scenario, spacing_m: float = 10.0) -> tuple[list[float], list[float]]:
    """(distances [m], speeds [m/s]) of the nominal noise-free run up to its first stop."""
    p = scenario.parameter
    vehicle = VehicleParams(mass=p("est.mass_initial"), A0=p("est.A0_initial"), A1=p("est.A1_initial"),
                            A2=p("est.A2_initial"), gamma=p("car.gamma"), length=p("car.length"),
                            traction_force_max=p("car.traction_force_max"),
                            traction_power_max=p("car.traction_power_max"),
                            brake_force_max=p("car.brake_force_max"))
    grade = GradeProfile.level()
    if p("track.grade_profile"):
        path = profile_file(p("track.grade_profile"), None)
        grade = GradeProfile.from_csv_text(read_text(path, ScenarioError), str(path))
    chain = open_chain(ChainConfig(vehicle=vehicle, process_noise_psd=0.0,
                                     filter=FilterConfig(speed_std=1e-9, position_std=1e-9)), grade)
    driver = PhaseDriver(scenario.phases, vehicle.mass, vehicle.traction_force_max, vehicle.brake_force_max)
    h = scenario.step_s
    xs, vs = [0.0], [0.0]
    moved = False
    for k in range(int(round(scenario.duration_s / h))):
        out = chain.outputs()
        f, b, _ = driver.demands(k * h, out["car.speed"], out["car.position"])
        chain.do_step(k * h, h, f, b, 0.0)
        out = chain.outputs()
        speed, position = out["car.speed"], out["car.position"]
        if speed > 0:
            moved = True
        if position >= xs[-1] + spacing_m or (moved and speed <= 0.0):
            if position > xs[-1]:
                xs.append(position)
                vs.append(speed)
        if moved and speed <= 0.0:
            break
    return xs, vs


def profile_csv_text(distances, speeds) -> str:
    return "distance_m,speed_mps\n" + "".join(f"{d:.3f},{v:.4f}\n" for d, v in zip(distances, speeds))
