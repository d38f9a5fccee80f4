"""planner.plant: any model to the loop plant, by type."""

import numpy as np
import pytest

from ident.models.lti import LoopPlant
from ident.models.vehicle import FullCarModel, build_full_car, example_vehicle
from planner.plant import MODEL_TYPES, FrfPlant, as_loop_plant


def test_each_model_type_gives_its_plant():
    params = example_vehicle()
    car = build_full_car(params)
    plant = as_loop_plant(car)
    assert isinstance(car, FullCarModel) and isinstance(plant, LoopPlant)
    assert as_loop_plant(plant) is plant
    from_params = as_loop_plant(params)
    assert isinstance(from_params, LoopPlant)
    f = np.array([1.0, 5.0])
    np.testing.assert_array_equal(from_params.frequency_response(f), plant.frequency_response(f))
    frf = FrfPlant(f, plant.frequency_response(f), plant.output_names, np.full(4, 3000.0))
    assert as_loop_plant(frf) is frf


def test_other_types_are_refused_by_name():
    class Duck:  # has the attributes the old duck typing looked for
        velocity_idx = np.arange(4)

        def frequency_response(self, f_hz):
            return None

    with pytest.raises(TypeError, match="VehicleModel, FullCarModel, VehicleParams, LoopPlant, "
                                        "FrfPlant .* got Duck"):
        as_loop_plant(Duck())
    assert len(MODEL_TYPES) == 5
