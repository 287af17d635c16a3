"""The service's web page: a static single-page app over the REST API, served at ``GET /``.

Only the files are served here (:mod:`service.api.web.routes`); everything the page shows comes
from the JSON API, with the user's token, so the page needs nothing the API does not offer.
"""

from service.api.web.routes import OPEN_PATHS, router

__all__ = ["OPEN_PATHS", "router"]
