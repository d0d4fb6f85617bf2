"""A plug-in effect of one's own: the coat softens with the lab temperature.

Use it by naming the module (never from a study file's contents):

    PYTHONPATH=examples surrogate simulate --ecoat 1 --scoat 0.2 --tcoat 0.012 \\
        --plugin my_effects --effect temperature:c_per_k=0.02 --condition temperature_c=30
    PYTHONPATH=examples surrogate calibrate STUDY.toml --plugin my_effects --effect temperature

``reads`` names the measurement column it needs; a measured file's
``temperature_c`` column then reaches ``apply`` as a test condition.
"""

import surrogate


class Temperature(surrogate.Effect):
    name = "temperature"
    description = "Ecoat and Scoat fall linearly with the temperature above 23 °C"
    parameters = (surrogate.EffectParameter("c_per_k", 0.0, 0.05, 0.0, "1/K"),)
    reads = ("temperature_c",)

    def apply(self, state, values, conditions):
        warmer = float(conditions.get("temperature_c", 23.0)) - 23.0
        scale = max(1.0 - values["c_per_k"] * warmer, 0.05)
        return state.replace(ecoat_mpa=state.ecoat_mpa * scale, scoat_mpa=state.scoat_mpa * scale)


surrogate.register_effect(Temperature)
