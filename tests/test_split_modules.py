"""The split modules keep their old import paths: renamed modules warn and still work, moved names re-export."""

import importlib
import warnings

import pytest


def test_geometry_multilevel_is_coarse_and_warns():
    import defop.geometry.coarse as coarse

    old = importlib.import_module("defop.geometry.multilevel")
    with pytest.warns(DeprecationWarning, match="defop.geometry.coarse"):
        f = old.coarse_mesh_of
    assert f is coarse.coarse_mesh_of
    with pytest.raises(AttributeError):
        old.no_such_name  # noqa: B018


def test_new_geometry_modules_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from defop.geometry.coarse import coarse_mesh_of, prolongate  # noqa: F401
        from defop.geometry.mesh_checks import check_closed_surface  # noqa: F401
        from defop.geometry.simplices import boundary_facets, signed_volumes  # noqa: F401


def test_mesh_module_keeps_its_names():
    import defop.geometry.mesh as mesh
    import defop.geometry.mesh_checks as checks
    import defop.geometry.simplices as simplices

    for name in ("signed_volumes", "signed_areas", "cotangent_laplacian", "boundary_facets", "ELEMENT", "FACETS"):
        assert getattr(mesh, name) is getattr(simplices, name)
    assert mesh.check_closed_surface is checks.check_closed_surface
    assert mesh.SAFE_DIAGONAL == simplices.SAFE_DIAGONAL


def test_plot_module_keeps_every_name():
    import defop.view.plot as plot
    import defop.view.plot_bases as bases
    import defop.view.plot_energies as energies
    import defop.view.plot_trajectory_maps as trajectories

    for mod in (bases, energies, trajectories):
        for name in mod.__all__:
            assert getattr(plot, name) is getattr(mod, name)
    for name in ("plot_shape", "plot_deformation", "region_outlines", "readable", "figure_key", "NAMES", "FLIP"):
        assert hasattr(plot, name)


def test_render_module_keeps_the_headless_names():
    import defop.view.headless as headless
    import defop.view.render as render

    for name in headless.__all__:
        assert getattr(render, name) is getattr(headless, name)


def test_figures_package_keeps_the_main_jobs_names():
    import defop.figures as figures

    for name in figures.__all__:
        assert hasattr(figures, name), name
    assert figures.ROOT / "notebooks" == figures.NOTEBOOKS and (figures.ROOT / "defop" / "figures").is_dir()
    assert figures.RUNTIMES == figures.ROOT / "figures" / "runtimes.json"


def test_shapes_module_keeps_its_names():
    import defop.scene.handles as handles
    import defop.scene.planar_shapes as planar_shapes
    import defop.scene.shape as shape
    import defop.scene.shapes as shapes

    assert shapes.Shape is shape.Shape
    assert shapes.from_polygon is planar_shapes.from_polygon and shapes.from_image is planar_shapes.from_image
    for name in handles.__all__:
        assert getattr(shapes, name) is getattr(handles, name)
    assert shapes.MAX_AUTO_HANDLES == planar_shapes.MAX_AUTO_HANDLES


def test_plot_trajectories_is_the_function():
    import defop.view.plot as plot

    assert callable(plot.plot_trajectories) and plot.plot_trajectories.__name__ == "plot_trajectories"
