"""The API's routers, one per resource; ``service.app.create_app`` includes them."""
