"""The app's HTTP routes and its WebSocket, one module per concern.

Each module has an ``add_routes(ctx)`` (``common.PageContext``), named by its entry in the page
registry ``skinloc.app.pages``, which ``skinloc.app.server.create_app`` reads. Every action that
changes something names its tab in ``X-Skinloc-Client`` and first takes control
(``Workspace.require``: 409 when another tab has it): the routes are added to an
``actions_router`` (``routes.common``), whose dependency does that for every action.
"""
