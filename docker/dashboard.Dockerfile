# rq-dashboard with the same RQ major as the app (job records of one RQ major are not always
# readable by another, so a prebuilt dashboard image with an old rq may show errors).
FROM python:3.11-slim

ARG RQ_DASHBOARD_VERSION=0.9.0
ARG RQ_VERSION=3.0.0

RUN pip install --no-cache-dir --disable-pip-version-check \
        "rq-dashboard==${RQ_DASHBOARD_VERSION}" "rq==${RQ_VERSION}" \
    && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin rqdash

USER 10001
EXPOSE 9181
CMD ["rq-dashboard", "--bind", "0.0.0.0", "--port", "9181"]
