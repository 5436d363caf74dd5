"""stub"""


def render(record):
    return ""
