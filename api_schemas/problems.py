"""Problem-details error bodies (RFC 9457, ``application/problem+json``)."""

from __future__ import annotations

from pydantic import BaseModel, Field

__all__ = ["InvalidParam", "Problem", "PROBLEM_MEDIA_TYPE"]

PROBLEM_MEDIA_TYPE = "application/problem+json"


class InvalidParam(BaseModel):
    """One thing wrong with a request, located as precisely as the input allows."""

    message: str = Field(description="What is wrong.")
    camera: str | None = Field(default=None, description="The camera concerned.")
    file: str | None = Field(default=None,
                             description="The uploaded file (as the client named it).")
    frame: int | None = Field(default=None, description="The frame concerned.")
    field: str | None = Field(default=None,
                              description="The field, option or form part concerned.")


class Problem(BaseModel):
    """An error answer. Never carries a stack trace."""

    type: str = Field(default="about:blank", description="URI naming the kind of problem.")
    title: str = Field(description="Short summary of the kind of problem.")
    status: int = Field(description="The HTTP status code.")
    detail: str | None = Field(default=None, description="What went wrong in this request.")
    instance: str | None = Field(default=None, description="The request path.")
    errors: list[InvalidParam] = Field(
        default_factory=list, description="Each problem found in the input, located."
    )
