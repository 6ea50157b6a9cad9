from capture.config import Config
from tui.app import WalkcapApp


async def test_app_opens_and_quits_with_q():
    config = Config()
    app = WalkcapApp(config)
    async with app.run_test() as pilot:
        assert "mock" in str(app.query_one("#placeholder").render())
        await pilot.press("q")
    assert app.return_code == 0 or app.return_code is None
